"""ASAM's Quality Checker bundles on an export: `qc_openscenario` (asam-qc-openscenarioxml) on an .xosc,
`qc_opendrive` (asam-qc-opendrive) on an .xodr; each writes its findings as an .xqar result file.

They pin lxml < 6 (the project's is 6), so they live in a virtual environment of their own: $GARAGE_EXP_QC (its
bin folder), else `.venv-qc/bin` in the checkout (`make setup` builds it).
"""

from __future__ import annotations

import os
import subprocess
import tempfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

from garage_exp.core import paths
from garage_exp.core.errors import GarageError

QC_ENV = "GARAGE_EXP_QC"
BUNDLES = {".xosc": ("qc_openscenario", "xoscBundle"), ".xodr": ("qc_opendrive", "xodrBundle")}


def qc_bin() -> Path:
    """The folder holding qc_openscenario and qc_opendrive; GarageError saying where it looked."""
    env = os.environ.get(QC_ENV)
    folder = Path(env).expanduser() if env else paths.PROJECT_ROOT / ".venv-qc" / "bin"
    if all((folder / tool).is_file() for tool, _ in BUNDLES.values()):
        return folder
    raise GarageError("no ASAM Quality Checker bundles (qc_openscenario, qc_opendrive): `make setup` installs them",
                      f"{QC_ENV}={env}" if env else str(folder))


def checkers(path: Path, timeout: float = 300.0) -> list[dict]:
    """What each checker of the bundle for the file's kind did with it: {"checker", "status" (completed | skipped
    | error), "summary" (why it skipped), "issues" (one line each: checker, level, description)}. A checker that
    did not complete checked nothing: no issue from it proves nothing. It skips a rule of another version of the
    standard than the file's, and any rule whose preconditions (a valid schema, a readable road file) failed."""
    tool, bundle = BUNDLES[Path(path).suffix]
    with tempfile.TemporaryDirectory() as tmp:
        config, result = Path(tmp) / "config.xml", Path(tmp) / "result.xqar"
        config.write_text(f'<?xml version="1.0"?><Config><Param name="InputFile" value={quoteattr(str(Path(path).resolve()))}/>'
                          f'<CheckerBundle application="{bundle}"><Param name="resultFile" value={quoteattr(str(result))}/>'
                          "</CheckerBundle></Config>")
        done = subprocess.run([str(qc_bin() / tool), "-c", str(config)], cwd=tmp, capture_output=True, text=True,
                              timeout=timeout)
        if done.returncode != 0 or not result.is_file():
            raise GarageError(f"{tool} exited {done.returncode}: {done.stderr.strip()[-300:]}", str(path))
        from lxml import etree

        root = etree.parse(str(result)).getroot()
        return [{"checker": (name := checker.get("checkerId")), "status": checker.get("status"),
                 "summary": checker.get("summary") or "",
                 "issues": [f"{name} {issue.get('level')} {issue.get('description')}"
                            for issue in checker.iter("Issue")]}
                for checker in root.iter("Checker")]


def issues(path: Path, timeout: float = 300.0) -> list[str]:
    """What the bundle for the file's kind reports on it: one line per issue (checker, level, description)."""
    return [line for checker in checkers(path, timeout) for line in checker["issues"]]
