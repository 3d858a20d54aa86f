"""The ASAM schemas (XSD) of OpenSCENARIO and OpenDRIVE that `scenariogeneration` ships, and a check of a file
against them that fails with one line naming the file and the element.

Shared by the writers (xosc_write.py, xodr_write.py: their tests validate what they write) and the importer
(garage_exp/openscenario/xosc_import.py: a file that fails the schema is refused before anything is read from it).
"""

from __future__ import annotations

from pathlib import Path

from garage_exp.core.state import STATE
from garage_exp.core.errors import GarageError

OSC_SCHEMAS = {"0": "OpenSCENARIO_1_0.xsd", "1": "OpenSCENARIO_1_1.xsd", "2": "OpenSCENARIO_1_2.xsd",
               "3": "OpenSCENARIO_1_3_1.xsd"}
XODR_SCHEMA = "opendrive_17_core.xsd"


def schemas_dir() -> Path:
    """site-packages/schemas: scenariogeneration installs the XSDs beside its package (its own reader looks
    there too)."""
    import scenariogeneration

    return Path(scenariogeneration.__file__).resolve().parent.parent / "schemas"


@STATE.memo("process", maxsize=8)
def _schema(name: str):
    import xmlschema

    return xmlschema.XMLSchema(str(schemas_dir() / name))


def parse(path: Path):
    """The file's XML tree; a file that is not XML is one line naming it and where the parser stopped."""
    from lxml import etree

    try:
        return etree.parse(str(path))
    except OSError as exc:
        raise GarageError(f"cannot read it: {exc}", str(path)) from None
    except etree.XMLSyntaxError as exc:
        line = exc.position[0] if exc.position else "?"
        raise GarageError(f"not XML (line {line}): {exc.msg}", str(path)) from None


def validate(path: Path, tree=None) -> str:
    """Check an .xosc against the OpenSCENARIO schema of the version its FileHeader names, or an .xodr against
    OpenDRIVE 1.7; returns the schema's file name. GarageError naming the file and the first invalid element."""
    tree = tree if tree is not None else parse(path)
    root = tree.getroot()
    if root.tag == "OpenDRIVE":
        name = XODR_SCHEMA
    elif root.tag == "OpenSCENARIO":
        header = root.find("FileHeader")
        major = header.get("revMajor") if header is not None else None
        minor = header.get("revMinor") if header is not None else None
        if major != "1" or minor not in OSC_SCHEMAS:
            raise GarageError(f"OpenSCENARIO {major}.{minor} has no schema here (1.0 to 1.3)",
                              f"{path}: FileHeader")
        name = OSC_SCHEMAS[minor]
    else:
        raise GarageError(f"the root element is <{root.tag}>, not <OpenSCENARIO> or <OpenDRIVE>", str(path))
    error = next(iter(_schema(name).iter_errors(tree)), None)
    if error is not None:
        element = getattr(error, "elem", None)
        where = tree.getpath(element) if element is not None and hasattr(tree, "getpath") else error.path
        line = f" (line {element.sourceline})" if element is not None and getattr(element, "sourceline", None) else ""
        reason = (error.reason or str(error).splitlines()[0]).strip().rstrip(".")
        raise GarageError(f"fails the schema {name}{line}: {reason}", f"{path}: {where}")
    return name
