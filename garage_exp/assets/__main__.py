"""`python -m garage_exp.assets where|ensure|fetch|convert|people`.

where:   print the vehicles and models folders in use (or what is missing).
ensure:  like where, but fetch whatever is missing, build the people library and fetch the loop's street photos
         (used by `make data`; a no-op when ../shared has both and the bodies and photos are in the cache).
fetch:   download the FlightGear vehicles and the official Ultralytics weights into the cache.
convert: convert every vehicle to GLB now instead of on first use, and list the library.
people:  build the prebuilt people (anny bodies) if missing, and list them.
"""

from __future__ import annotations

import argparse
import logging
import sys

from garage_exp.assets import locate
from garage_exp.core import shell
from garage_exp.core.errors import GarageError


def _where() -> int:
    missing = 0
    for what, find in (("vehicles", locate.vehicles_dir), ("models", locate.models_dir)):
        try:
            print(f"{what}: {find()}")
        except GarageError as exc:
            print(f"{what}: missing ({exc})")
            missing += 1
    return 1 if missing else 0


def _ensure() -> int:
    try:
        locate.vehicles_dir()
    except GarageError:
        print(f"fetching vehicles ({locate.DEB_PACKAGE}) ...", flush=True)
        locate.fetch_vehicles()
    try:
        locate.models_dir()
    except GarageError:
        print(f"fetching detector weights {', '.join(locate.MODEL_WEIGHTS)} ...", flush=True)
        locate.fetch_models()
    found = _where()
    _excluded()
    _people(verbose=False)
    _street_photos()
    return found


def _street_photos() -> None:
    """The loop's street photos (assets/photos.py), fetched once; without apt, one line says what is missing."""
    from garage_exp.assets import photos

    try:
        photos.street_photos()
    except GarageError:
        try:
            print("fetching the street photos (opencv-doc, node-opencv) ...", flush=True)
            photos.fetch_street_photos()
        except GarageError as exc:
            print(f"street photos: missing ({exc})")


def _excluded() -> None:
    """The vehicles left out of the library, said once here at set-up rather than by every command."""
    from garage_exp.assets.vehicles import VehicleLibrary

    excluded = VehicleLibrary().excluded
    if excluded:
        print(f"vehicles excluded as implausible in a garage: {', '.join(excluded)} "
              "(`python -m garage_exp.assets convert` says why)")


def _fetch() -> int:
    print(f"fetching vehicles ({locate.DEB_PACKAGE}) ...", flush=True)
    print(f"vehicles fetched into {locate.fetch_vehicles()}")
    print(f"fetching detector weights {', '.join(locate.MODEL_WEIGHTS)} ...", flush=True)
    print(f"models fetched into {locate.fetch_models()}")
    return _where()


def _convert() -> int:
    from garage_exp.assets.vehicles import VehicleLibrary

    library = VehicleLibrary()
    for model in library.models:
        print(f"{model.name:22s} {model.length:5.2f} x {model.width:4.2f} x {model.height:4.2f} m "
              f"{model.size_class:6s} {model.kind:6s} {model.colour:6s} {model.glb}")
    for name, reason in library.excluded.items():
        print(f"{name:22s} excluded: {reason}")
    return 0


def _people(verbose: bool = True) -> int:
    import time

    from garage_exp.assets.people import PeopleLibrary

    start = time.perf_counter()
    library = PeopleLibrary()
    models = library.library()
    print(f"people: {len(models)} bodies in {library.root} ({library.built} built, "
          f"{time.perf_counter() - start:.1f} s)")
    for m in models if verbose else ():
        print(f"{m.name:38s} {m.length:4.2f} x {m.width:4.2f} x {m.height:4.2f} m {m.glb}")
    return 0


COMMAND = shell.Command("garage_exp.assets")
COMMANDS = {"where": _where, "ensure": _ensure, "fetch": _fetch, "convert": _convert, "people": _people}


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    return COMMANDS[args.command]()


def main(argv: list[str] | None = None) -> int:
    """The command in the one shell (garage_exp.core.shell): bad input one line and 2, Ctrl-C 130, SIGTERM 143;
    `where` and `ensure` exit 1 when something is still missing."""
    parser = argparse.ArgumentParser(prog="python -m garage_exp.assets", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=tuple(COMMANDS))
    return COMMAND.run_args(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
