"""`callable:package.module:function`: the user's own detection code as an entry.

The function is called with a batch: `function(frames, intrinsics)`, frames a list of HxWx3 uint8 RGB arrays,
intrinsics a list of the same length (one `scene.lenses.Lens` per frame, or None where the caller has no camera),
and returns a list of one `Detections` per frame (boxes x1, y1, x2, y2 in the frame's pixels, scores in [0, 1],
class names). Its class names are declared as an attribute, `function.classes = ["car", "person"]`, or given in
the config (`detector.class_names.FUNCTION`): preflight checks them against the scored classes and
`detector.class_map`, and refuses a function whose names are unknown (it would score 0 on every frame, without a
word, if it answered only names the job cannot score); a name answered that is not among them fails the job.
Its module must lie under an allowed prefix (core.plugins:
garage_exp., or $GARAGE_EXP_MODIFIER_MODULES), as other user code does.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.perception.detect.base import (DEFAULT_CAMERA, Detections, Entry, EntrySettings, checked,
                                               message_of, probe_frame)
from garage_exp.perception.detect.kinds import register_entry_kind
from garage_exp.scene.lenses import Lens

PREFIX = "callable:"


@register_entry_kind("callable", prefix=PREFIX)
class CallableEntry(Entry):
    kind = "callable"

    def __init__(self, entry: str, settings: EntrySettings):
        from garage_exp.core.plugins import check_target

        super().__init__(entry, settings)
        target = self.entry[len(PREFIX):]
        module, sep, name = target.partition(":")
        if not module or not sep or not name or ":" in name:
            raise self.fail(f"{target!r} is not \"package.module:function\"")
        self.dotted = f"{module}.{name}"
        check_target(self.dotted, "a detector function", self.where)  # the allow-list, before anything loads
        self.name = name
        self.device = "user code"
        self._function = None

    def check(self, intrinsics: Lens | None = None) -> None:
        from garage_exp.core.plugins import resolve

        if self._function is not None:
            return
        function = resolve(self.dotted, "a detector function", self.where)
        if not callable(function):
            raise self.fail(f"{self.dotted} is a {type(function).__name__}, not a function")
        declared = getattr(function, "classes", ())
        if isinstance(declared, str) or not all(isinstance(c, str) for c in declared):
            raise self.fail("its `classes` attribute must be a list of class-name strings")
        self.classes = tuple(declared) or self.given_classes
        if not self.classes:
            raise self.fail(f"its class names are unknown, so preflight cannot check that the job can score them: "
                            f"declare them ({self.name}.classes = [\"car\", \"person\"]) or give them, "
                            f"+detector.class_names.{self.name}=[car,person]")
        self._function = function
        try:
            self.detect([probe_frame(intrinsics)], [intrinsics or DEFAULT_CAMERA])
        except GarageError as exc:
            self._function = None
            raise GarageError(f"on a probe frame: {message_of(exc)}", self.where) from None

    def detect(self, frames: Sequence[np.ndarray], intrinsics: Sequence[Lens | None]) -> list[Detections]:
        try:
            out = self._function(list(frames), list(intrinsics))
        except GarageError:
            raise
        except Exception as exc:  # noqa: BLE001 - the user's code: one line naming the entry
            first = (str(exc).strip().splitlines() or [""])[0]
            raise self.fail(f"raised {type(exc).__name__}: {first}"[:300]) from None
        if not isinstance(out, (list, tuple)) or len(out) != len(frames):
            got = f"{type(out).__name__} of {len(out)}" if isinstance(out, (list, tuple)) else type(out).__name__
            raise self.fail(f"returned {got}, not a list of one Detections per frame ({len(frames)})")
        try:
            found = [checked(d, rgb, f"result[{k}]") for k, (d, rgb) in enumerate(zip(out, frames))]
        except ValueError as exc:
            raise self.fail(f"returned {exc}") from None
        stray = sorted({c for d in found for c in d.classes} - set(self.classes))
        if stray:  # the checked names are what preflight held against the scored classes: no others
            raise self.fail(f"returned class(es) {stray}, not among its classes ({', '.join(self.classes)})")
        return found
