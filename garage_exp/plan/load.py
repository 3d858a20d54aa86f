"""Read a plan from YAML or CSV and validate it; every failure is one line naming the file and place."""

from __future__ import annotations

import csv
import math
from collections import deque
from pathlib import Path

import numpy as np
import yaml

from garage_exp.core.errors import GarageError
from garage_exp.plan.model import DRIVEABLE, ENTRANCE, Plan

MAX_CELLS_PER_SIDE = 500
MAX_FILE_BYTES = 4_000_000  # the largest plan (500 x 500 cells) is ~1 MB of YAML or CSV
MAX_YAML_DEPTH = 32
METRES_RANGE = (0.5, 100.0)  # a row depth or column width outside this is a unit mistake
YAML_KEYS = {"S", "R", "C", "name", "garage"}
# A plan file's optional `garage:` mapping (a generated plan's, plan/generator.py): the garage values it was sized
# for, within these sane ranges (scene/structure.py checks the garage group's own again).
PLAN_GARAGE_KEYS = {"ceiling_height": (1.8, 10.0), "pillar_size": (0.05, 3.0), "bay_width": (1.5, 20.0)}


def load_plan(path: str | Path, name: str | None = None) -> Plan:
    """Load and validate a plan file (.yaml/.yml, or .csv with C on the first row and R in the first column)."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise GarageError("plan file not found", where)
    if path.stat().st_size > MAX_FILE_BYTES:
        raise GarageError(f"file is larger than {MAX_FILE_BYTES // 1_000_000} MB; not a plan", where)
    try:
        # utf-8-sig: spreadsheets save "CSV UTF-8" with a byte-order mark
        text = path.read_text(encoding="utf-8-sig")
    except (UnicodeDecodeError, OSError) as exc:
        raise GarageError(f"cannot read as UTF-8 text ({type(exc).__name__})", where) from None
    if not text.strip():
        raise GarageError("file is empty", where)
    if path.suffix.lower() == ".csv":
        S, R, C, file_name = _parse_csv(text, where)
    else:
        S, R, C, file_name, garage = _parse_yaml(text, where)
        return plan_from_lists(S, R, C, name or file_name or path.stem, where, garage)
    return plan_from_lists(S, R, C, name or file_name or path.stem, where)


def plan_from_lists(S, R, C, name: str, where: str = "<memory>", garage=None) -> Plan:
    """Validate raw S, R, C (lists or arrays) and the optional garage values, and build a Plan."""
    s = _matrix(S, where)
    m, n = s.shape
    r = _vector(R, "R", m, column=True, where=where)
    c = _vector(C, "C", n, column=False, where=where)
    plan = Plan(name=str(name), S=s, R=r, C=c, source=where, garage=_garage(garage, where))
    _check_connectivity(plan, where)
    return plan


def _safe_load(text: str, where: str):
    """YAML as plain data (safe loading only: no Python objects, a plan is data). libyaml's safe loader, when
    installed, is ~6x faster on a big plan, but its composer recurses in C and crashes the process on a file
    nested a million levels deep; its event parser does not, so the depth is checked on the events first."""
    if not hasattr(yaml, "CSafeLoader"):
        return yaml.safe_load(text)  # pure Python: deep nesting is a RecursionError, caught by the caller
    depth = 0
    for event in yaml.parse(text, Loader=yaml.CSafeLoader):
        if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                line = event.start_mark.line + 1 if event.start_mark else "?"
                raise GarageError(f"line {line}: nested more than {MAX_YAML_DEPTH} levels deep (a plan has 3)",
                                  where)
        elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            depth -= 1
    return yaml.load(text, Loader=yaml.CSafeLoader)


def _parse_yaml(text: str, where: str):
    try:
        data = _safe_load(text, where)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        place = f"line {mark.line + 1}" if mark is not None else "?"
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise GarageError(f"{place}: {problem}", where) from None
    except (ValueError, RecursionError) as exc:  # a 5000-digit integer, brackets nested thousands deep
        raise GarageError(f"unreadable YAML ({type(exc).__name__}: {str(exc)[:80]})", where) from None
    if not isinstance(data, dict):
        raise GarageError(f"expected a mapping with keys S, R, C; got {type(data).__name__}", where)
    unknown = set(map(str, data)) - YAML_KEYS
    if unknown:
        raise GarageError(f"unknown key(s) {sorted(unknown)}; expected S, R, C and optional name, garage", where)
    for key in ("S", "R", "C"):
        if key not in data:
            raise GarageError(f"missing key {key}", where)
    name = data.get("name")
    if name is not None and not isinstance(name, (str, int)):
        raise GarageError("name must be a string", where)
    return data["S"], data["R"], data["C"], None if name is None else str(name), data.get("garage")


def _garage(values, where: str) -> tuple[tuple[str, float], ...]:
    """A plan's `garage:` mapping (PLAN_GARAGE_KEYS) as sorted (key, value) pairs; () when it has none."""
    if values is None:
        return ()
    if not isinstance(values, dict):
        raise GarageError(f"garage must be a mapping of {', '.join(PLAN_GARAGE_KEYS)}; got {_shown(values)}", where)
    out = []
    for key, value in values.items():
        if key not in PLAN_GARAGE_KEYS:
            raise GarageError(f"garage.{key}: unknown (a plan may set {', '.join(PLAN_GARAGE_KEYS)})", where)
        lo, hi = PLAN_GARAGE_KEYS[key]
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(float(value)) or not lo <= float(value) <= hi:
            raise GarageError(f"garage.{key}: {_shown(value)} is not a length in {lo:g}-{hi:g} m", where)
        out.append((str(key), float(value)))
    return tuple(sorted(out))


def _parse_csv(text: str, where: str):
    # Drop comments before parsing: a quote inside a comment would otherwise open a field that eats lines.
    lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]
    try:
        rows = [[cell.strip() for cell in r] for r in csv.reader(lines) if any(cell.strip() for cell in r)]
    except csv.Error as exc:
        raise GarageError(f"not a CSV plan ({exc})", where) from None
    if len(rows) < 2:
        raise GarageError("CSV needs a header row of column widths and at least one plan row", where)
    header = rows[0]
    C = [_csv_number(v, where, f"row 1, column {k + 2}") for k, v in enumerate(header[1:])]
    R, S = [], []
    for k, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise GarageError(f"row {k}: {len(row)} fields, header has {len(header)}", where)
        R.append(_csv_number(row[0], where, f"row {k}, column 1"))
        S.append([_csv_number(v, where, f"row {k}, column {q + 2}") for q, v in enumerate(row[1:])])
    return S, R, C, None


def _csv_number(value: str, where: str, place: str):
    try:
        number = float(value)
    except ValueError:
        raise GarageError(f"{place}: {value!r} is not a number", where) from None
    return int(number) if number.is_integer() and "." not in value else number


def _shown(value) -> str:
    """A value for a message: containers by their kind (the repr of a list nested 3000 deep recurses), others
    by a repr cut to a readable length."""
    if isinstance(value, (list, tuple, dict, np.ndarray)):
        return f"a {type(value).__name__}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _matrix(S, where: str) -> np.ndarray:
    if not isinstance(S, (list, tuple, np.ndarray)) or len(S) == 0:
        raise GarageError("S must be a non-empty list of rows", where)
    # Sizes first: YAML aliases repeat a 500-cell row a million times in a few MB, and checking every value of
    # such a matrix before its size would take minutes.
    if len(S) > MAX_CELLS_PER_SIDE:
        raise GarageError(f"S has {len(S)} rows; at most {MAX_CELLS_PER_SIDE} cells per side", where)
    width = None
    for i, row in enumerate(S):
        if not isinstance(row, (list, tuple, np.ndarray)) or len(row) == 0:
            raise GarageError(f"S row {i}: must be a non-empty list of integers", where)
        if len(row) > MAX_CELLS_PER_SIDE:
            raise GarageError(f"S row {i} has {len(row)} columns; at most {MAX_CELLS_PER_SIDE} cells per side",
                              where)
        if width is None:
            width = len(row)
        elif len(row) != width:
            raise GarageError(f"S row {i}: {len(row)} columns, row 0 has {width} (ragged matrix)", where)
        for j, v in enumerate(row):
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise GarageError(f"S row {i}, column {j}: {_shown(v)} is not an integer", where)
            if not -1 <= int(v) <= 3:
                shown = int(v) if abs(int(v)) < 10**6 else "out of range"  # str() of 5000 digits raises
                raise GarageError(
                    f"S row {i}, column {j}: value {shown} is not one of -1 obstacle, 0 parking, 1 lane, "
                    "2 entrance, 3 exit", where)
    m, n = len(S), width
    if m > MAX_CELLS_PER_SIDE or n > MAX_CELLS_PER_SIDE:
        raise GarageError(f"S is {m} x {n}; at most {MAX_CELLS_PER_SIDE} cells per side", where)
    return np.asarray(S, dtype=np.int8).reshape(m, n)


def _vector(values, key: str, length: int, column: bool, where: str) -> np.ndarray:
    """R (m x 1, column=True) or C (1 x n): accept the flat form or the nested matrix form."""
    if not isinstance(values, (list, tuple, np.ndarray)) or len(values) == 0:
        raise GarageError(f"{key} must be a non-empty list of numbers", where)
    nested = all(isinstance(v, (list, tuple, np.ndarray)) for v in values)
    if nested:
        rows = [list(v) for v in values]
        shape = (len(rows), len(rows[0]) if rows else 0)
        if any(len(r) != shape[1] for r in rows):
            raise GarageError(f"{key} is ragged", where)
        if column:
            if shape[1] != 1:
                raise GarageError(f"R must be m x 1; got {shape[0]} x {shape[1]}", where)
            flat = [r[0] for r in rows]
        else:
            if shape[0] != 1:
                raise GarageError(f"C must be 1 x n; got {shape[0]} x {shape[1]}", where)
            flat = rows[0]
    elif any(isinstance(v, (list, tuple, np.ndarray)) for v in values):
        raise GarageError(f"{key} mixes numbers and lists", where)
    else:
        flat = list(values)
    if len(flat) != length:
        what = "rows of S" if column else "columns of S"
        raise GarageError(f"{key} has {len(flat)} entries but S has {length} {what}", where)
    lo, hi = METRES_RANGE
    for k, v in enumerate(flat):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise GarageError(f"{key}[{k}]: {_shown(v)} is not a number", where)
        try:
            f = float(v)
        except OverflowError:
            raise GarageError(f"{key}[{k}]: number too large", where) from None
        if not math.isfinite(f):
            raise GarageError(f"{key}[{k}]: {v} is not finite", where)
        if not lo <= f <= hi:
            raise GarageError(f"{key}[{k}]: {v} m is outside the sane range {lo}-{hi} m", where)
    return np.asarray(flat, dtype=float)


def _check_connectivity(plan: Plan, where: str) -> None:
    S = plan.S
    entrances = list(zip(*np.nonzero(S == ENTRANCE)))
    if not entrances:
        raise GarageError("no entrance (value 2) in S", where)
    seen = np.zeros(S.shape, dtype=bool)
    queue = deque((int(i), int(j)) for i, j in entrances)
    for i, j in queue:
        seen[i, j] = True
    while queue:
        i, j = queue.popleft()
        for _, a, b in plan.neighbours(i, j):
            if not seen[a, b] and int(S[a, b]) in DRIVEABLE:
                seen[a, b] = True
                queue.append((a, b))
    stranded = np.argwhere(np.isin(S, DRIVEABLE) & ~seen)
    if len(stranded):
        i, j = map(int, stranded[0])
        kind = {1: "lane", 2: "entrance", 3: "exit"}[int(S[i, j])]
        more = f" (and {len(stranded) - 1} more)" if len(stranded) > 1 else ""
        raise GarageError(f"S row {i}, column {j}: {kind} cell is not reachable from an entrance{more}", where)
