"""Every validation rule of garage_exp.plan.load, one test each: the error is a GarageError whose one-line
message names the file and, where there is one, the row/column or entry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from garage_exp.core.errors import GarageError
from garage_exp.plan import load_plan, plan_from_lists
from garage_exp.plan.load import MAX_CELLS_PER_SIDE, MAX_FILE_BYTES

GOOD_S = "[[0, 0, 0], [2, 1, 3]]"
GOOD = f"S: {GOOD_S}\nR: [5.0, 6.0]\nC: [2.5, 2.5, 2.5]\n"


def write(tmp_path: Path, text: str | bytes, name: str = "plan.yaml") -> Path:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
    return path


def error_of(path: Path) -> str:
    with pytest.raises(GarageError) as info:
        load_plan(path)
    message = str(info.value)
    assert "\n" not in message, "the CLI prints one line"
    assert message.startswith(f"{path}: "), f"the message names the file: {message}"
    return message[len(f"{path}: "):]


def yaml_error(tmp_path: Path, S: str = GOOD_S, R: str = "[5.0, 6.0]", C: str = "[2.5, 2.5, 2.5]",
               extra: str = "") -> str:
    return error_of(write(tmp_path, f"S: {S}\nR: {R}\nC: {C}\n{extra}"))


# --- loading that works ---------------------------------------------------------------------------

def test_good_yaml_loads(tmp_path):
    plan = load_plan(write(tmp_path, GOOD))
    assert plan.S.tolist() == [[0, 0, 0], [2, 1, 3]]
    assert plan.R.tolist() == [5.0, 6.0] and plan.C.tolist() == [2.5, 2.5, 2.5]
    assert plan.name == "plan" and plan.source == str(tmp_path / "plan.yaml")


def test_name_key_and_name_argument(tmp_path):
    path = write(tmp_path, "name: level_b2\n" + GOOD, "x.yml")
    assert load_plan(path).name == "level_b2"
    assert load_plan(path, name="other").name == "other"


def test_matrix_forms_of_R_and_C_are_accepted(tmp_path):
    plan = load_plan(write(tmp_path, f"S: {GOOD_S}\nR: [[5.0], [6.0]]\nC: [[2.5, 2.5, 2.5]]\n"))
    assert plan.R.tolist() == [5.0, 6.0] and plan.C.tolist() == [2.5, 2.5, 2.5]


def test_integer_metres_are_accepted(tmp_path):
    assert load_plan(write(tmp_path, f"S: {GOOD_S}\nR: [5, 6]\nC: [3, 3, 3]\n")).R.dtype == float


# --- file level -------------------------------------------------------------------------------------

def test_missing_file(tmp_path):
    assert error_of(tmp_path / "nope.yaml") == "plan file not found"


def test_directory_is_not_a_plan(tmp_path):
    (tmp_path / "d.yaml").mkdir()
    assert error_of(tmp_path / "d.yaml") == "plan file not found"


def test_empty_file(tmp_path):
    assert error_of(write(tmp_path, "")) == "file is empty"


def test_blank_file(tmp_path):
    assert error_of(write(tmp_path, " \n\t\n")) == "file is empty"


def test_huge_file(tmp_path):
    path = tmp_path / "huge.yaml"
    with path.open("wb") as f:  # sparse: the size check must come before any reading
        f.truncate(MAX_FILE_BYTES + 1)
    assert "larger than" in error_of(path)


def test_binary_junk(tmp_path):
    junk = bytes(range(256)) * 4
    assert "UTF-8" in error_of(write(tmp_path, junk))


def test_binary_junk_that_is_valid_utf8(tmp_path):
    # NUL and other control characters are valid UTF-8 but not YAML.
    assert error_of(write(tmp_path, "S: [[2]]\x00\x01\x02\nR: [5]\nC: [5]\n"))


def test_garbage_yaml_names_the_line(tmp_path):
    assert error_of(write(tmp_path, "S: [[2, 1]\nR: [5]\nC: [5, 5]\n")).startswith("line ")


def test_yaml_that_is_not_a_mapping(tmp_path):
    assert "expected a mapping" in error_of(write(tmp_path, "- 1\n- 2\n"))


def test_yaml_scalar(tmp_path):
    assert "expected a mapping" in error_of(write(tmp_path, "just words\n"))


def test_unknown_key(tmp_path):
    assert "unknown key(s) ['D']" in yaml_error(tmp_path, extra="D: 1\n")


@pytest.mark.parametrize("key", ["S", "R", "C"])
def test_missing_key(tmp_path, key):
    text = "\n".join(line for line in GOOD.splitlines() if not line.startswith(f"{key}:"))
    assert error_of(write(tmp_path, text)) == f"missing key {key}"


def test_name_must_be_a_string(tmp_path):
    assert error_of(write(tmp_path, "name: [a]\n" + GOOD)) == "name must be a string"


def test_python_tags_are_refused(tmp_path):
    assert "line 1" in error_of(write(tmp_path, "S: !!python/object/apply:os.getcwd []\nR: [5]\nC: [5]\n"))


# --- S ----------------------------------------------------------------------------------------------

def test_S_not_a_list(tmp_path):
    assert yaml_error(tmp_path, S="abc") == "S must be a non-empty list of rows"


def test_S_empty(tmp_path):
    assert yaml_error(tmp_path, S="[]") == "S must be a non-empty list of rows"


def test_S_row_not_a_list(tmp_path):
    assert yaml_error(tmp_path, S="[[0, 0, 0], 5]").startswith("S row 1: ")


def test_S_row_empty(tmp_path):
    assert yaml_error(tmp_path, S="[[0, 0, 0], []]").startswith("S row 1: ")


def test_ragged_rows(tmp_path):
    message = yaml_error(tmp_path, S="[[0, 0, 0], [2, 1]]")
    assert message.startswith("S row 1: 2 columns, row 0 has 3") and "ragged" in message


def test_value_4(tmp_path):
    assert yaml_error(tmp_path, S="[[0, 0, 0], [2, 1, 4]]").startswith("S row 1, column 2: value 4 ")


def test_value_minus_2(tmp_path):
    assert yaml_error(tmp_path, S="[[0, -2, 0], [2, 1, 3]]").startswith("S row 0, column 1: value -2 ")


def test_float_in_S(tmp_path):
    assert yaml_error(tmp_path, S="[[0, 0, 0], [2, 1.0, 3]]") == "S row 1, column 1: 1.0 is not an integer"


def test_bool_in_S(tmp_path):
    assert yaml_error(tmp_path, S="[[true, 0, 0], [2, 1, 3]]") == "S row 0, column 0: True is not an integer"


def test_string_in_S(tmp_path):
    assert yaml_error(tmp_path, S="[[0, '1', 0], [2, 1, 3]]") == "S row 0, column 1: '1' is not an integer"


def test_null_in_S(tmp_path):
    assert yaml_error(tmp_path, S="[[0, 0, ~], [2, 1, 3]]") == "S row 0, column 2: None is not an integer"


def test_nan_in_S(tmp_path):
    assert yaml_error(tmp_path, S="[[0, .nan, 0], [2, 1, 3]]") == "S row 0, column 1: nan is not an integer"


def test_too_many_cells_per_side(tmp_path):
    S = "[" + ", ".join(["[2]"] + ["[0]"] * MAX_CELLS_PER_SIDE) + "]"
    R = "[" + ", ".join(["5"] * (MAX_CELLS_PER_SIDE + 1)) + "]"
    assert f"at most {MAX_CELLS_PER_SIDE} cells per side" in yaml_error(tmp_path, S=S, R=R, C="[5]")


# --- R and C ----------------------------------------------------------------------------------------

def test_R_not_a_list(tmp_path):
    assert yaml_error(tmp_path, R="5") == "R must be a non-empty list of numbers"


def test_C_a_mapping(tmp_path):
    assert yaml_error(tmp_path, C="{a: 1}") == "C must be a non-empty list of numbers"


def test_R_as_1_by_m(tmp_path):
    assert yaml_error(tmp_path, R="[[5.0, 6.0]]") == "R must be m x 1; got 1 x 2"


def test_C_as_n_by_1(tmp_path):
    assert yaml_error(tmp_path, C="[[2.5], [2.5], [2.5]]") == "C must be 1 x n; got 3 x 1"


def test_R_ragged_matrix(tmp_path):
    assert yaml_error(tmp_path, R="[[5.0], [6.0, 1.0]]") == "R is ragged"


def test_R_mixes_numbers_and_lists(tmp_path):
    assert yaml_error(tmp_path, R="[5.0, [6.0]]") == "R mixes numbers and lists"


def test_R_wrong_length(tmp_path):
    assert yaml_error(tmp_path, R="[5.0, 6.0, 5.0]") == "R has 3 entries but S has 2 rows of S"


def test_C_wrong_length(tmp_path):
    assert yaml_error(tmp_path, C="[2.5, 2.5]") == "C has 2 entries but S has 3 columns of S"


def test_string_in_R(tmp_path):
    assert yaml_error(tmp_path, R="[5.0, six]") == "R[1]: 'six' is not a number"


def test_bool_in_C(tmp_path):
    assert yaml_error(tmp_path, C="[2.5, true, 2.5]") == "C[1]: True is not a number"


def test_nan_in_R(tmp_path):
    assert yaml_error(tmp_path, R="[.nan, 6.0]") == "R[0]: nan is not finite"


def test_inf_in_C(tmp_path):
    assert yaml_error(tmp_path, C="[2.5, 2.5, .inf]") == "C[2]: inf is not finite"


def test_negative_metres(tmp_path):
    assert yaml_error(tmp_path, R="[5.0, -6.0]").startswith("R[1]: -6.0 m is outside the sane range")


def test_zero_metres(tmp_path):
    assert yaml_error(tmp_path, C="[0, 2.5, 2.5]").startswith("C[0]: 0 m is outside the sane range")


def test_millimetres_instead_of_metres(tmp_path):
    assert yaml_error(tmp_path, C="[2500, 2500, 2500]").startswith("C[0]: 2500 m is outside the sane range")


# --- connectivity -----------------------------------------------------------------------------------

def test_no_entrance(tmp_path):
    assert yaml_error(tmp_path, S="[[0, 0, 0], [1, 1, 3]]") == "no entrance (value 2) in S"


def test_unreachable_lane(tmp_path):
    message = yaml_error(tmp_path, S="[[0, 0, 1], [2, 1, 0]]")
    assert message == "S row 0, column 2: lane cell is not reachable from an entrance"


def test_unreachable_exit_counts_the_rest(tmp_path):
    message = yaml_error(tmp_path, S="[[1, 0, 3], [2, -1, 1]]")
    assert message == "S row 0, column 2: exit cell is not reachable from an entrance (and 1 more)"


def test_diagonal_is_not_connected(tmp_path):
    assert "not reachable" in yaml_error(tmp_path, S="[[2, 0, 0], [0, 1, 0]]", R="[5, 5]")


def test_an_entrance_alone_is_a_plan(tmp_path):
    assert load_plan(write(tmp_path, "S: [[2]]\nR: [6]\nC: [6]\n")).shape == (1, 1)


# --- CSV --------------------------------------------------------------------------------------------

CSV = "# widths then rows\n,2.5,2.5,2.5\n5.0,0,0,0\n\n6.0, 2, 1, 3\n"


def test_csv_loads_with_comments_blank_lines_and_spaces(tmp_path):
    plan = load_plan(write(tmp_path, CSV, "p.csv"))
    assert plan.S.tolist() == [[0, 0, 0], [2, 1, 3]] and plan.R.tolist() == [5.0, 6.0]
    assert plan.C.tolist() == [2.5, 2.5, 2.5] and plan.name == "p"


def test_csv_suffix_is_case_insensitive(tmp_path):
    assert load_plan(write(tmp_path, CSV, "P.CSV")).shape == (2, 3)


def test_csv_with_byte_order_mark_before_the_header(tmp_path):
    assert load_plan(write(tmp_path, "\ufeff,2.5,2.5,2.5\n5,0,0,0\n6,2,1,3\n", "p.csv")).shape == (2, 3)


def test_csv_header_only(tmp_path):
    assert "header row" in error_of(write(tmp_path, ",2.5,2.5\n", "p.csv"))


def test_csv_comments_only(tmp_path):
    assert "header row" in error_of(write(tmp_path, "# nothing\n# here\n", "p.csv"))


def test_csv_ragged_row(tmp_path):
    assert error_of(write(tmp_path, ",2.5,2.5,2.5\n5.0,0,0\n6,2,1,3\n", "p.csv")) == "row 2: 3 fields, header has 4"


def test_csv_word_in_S(tmp_path):
    message = error_of(write(tmp_path, ",2.5,2.5,2.5\n5.0,0,x,0\n6,2,1,3\n", "p.csv"))
    assert message == "row 2, column 3: 'x' is not a number"


def test_csv_empty_field(tmp_path):
    message = error_of(write(tmp_path, ",2.5,2.5,2.5\n5.0,0,,0\n6,2,1,3\n", "p.csv"))
    assert message == "row 2, column 3: '' is not a number"


def test_csv_float_in_S(tmp_path):
    message = error_of(write(tmp_path, ",2.5,2.5,2.5\n5.0,0,0,0\n6,2,1.0,3\n", "p.csv"))
    assert message == "S row 1, column 1: 1.0 is not an integer"


def test_csv_value_4(tmp_path):
    message = error_of(write(tmp_path, ",2.5,2.5,2.5\n5.0,0,0,4\n6,2,1,3\n", "p.csv"))
    assert message.startswith("S row 0, column 2: value 4")


def test_csv_nan_depth(tmp_path):
    assert error_of(write(tmp_path, ",2.5,2.5,2.5\nnan,0,0,0\n6,2,1,3\n", "p.csv")) == "R[0]: nan is not finite"


def test_csv_semicolons_are_not_commas(tmp_path):
    assert "not a number" in error_of(write(tmp_path, ";2.5;2.5\n5;2;1\n", "p.csv"))


# --- bugs found in load.py (these fail until load.py is fixed; see the fix in each docstring) ---------

def test_csv_comment_with_a_quote_does_not_swallow_the_plan(tmp_path):
    """csv.reader runs before comment lines are dropped, so `,"` in a comment opens a quoted field that
    eats the following lines. Fix in _parse_csv: drop comment lines first, then parse:
    `lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]; csv.reader(lines)`."""
    plan = load_plan(write(tmp_path, '# C: widths,"R: depths (metres)\n' + CSV, "p.csv"))
    assert plan.shape == (2, 3)


def test_csv_word_in_header_names_its_file_column(tmp_path):
    """Plan rows name the file column (R is column 1), the header names one less: 'wide' is in column 3.
    Fix in _parse_csv: `f"row 1, column {k + 2}"` for the header, as for the plan rows."""
    message = error_of(write(tmp_path, ",2.5,wide,2.5\n5.0,0,0,0\n6,2,1,3\n", "p.csv"))
    assert message == "row 1, column 3: 'wide' is not a number"


def test_csv_with_byte_order_mark_and_a_leading_comment(tmp_path):
    """Spreadsheets save "CSV UTF-8" with a byte-order mark; read_text keeps it, so a first comment line
    starts with U+FEFF, not '#', and is taken as the header. Fix in load_plan: read_text(encoding="utf-8-sig")."""
    assert load_plan(write(tmp_path, "\ufeff" + CSV, "p.csv")).shape == (2, 3)


def test_csv_overlong_field_is_a_garage_error(tmp_path):
    """csv.Error ("field larger than field limit") escapes. Fix in _parse_csv: wrap the reader in
    `try: ... except csv.Error as exc: raise GarageError(f"not a CSV plan ({exc})", where) from None`."""
    error_of(write(tmp_path, ",2.5\n5," + "1" * 200_000 + "\n", "p.csv"))


def test_yaml_integer_too_long_to_convert_is_a_garage_error(tmp_path):
    """PyYAML's int constructor raises ValueError past Python's 4300-digit limit. Fix in _parse_yaml:
    `except (ValueError, RecursionError) as exc: raise GarageError(f"unreadable YAML ({exc})", where)`."""
    error_of(write(tmp_path, "S: [[2, 1" + "0" * 5000 + "]]\nR: [5]\nC: [5, 5]\n"))


def test_deeply_nested_yaml_is_a_garage_error(tmp_path):
    """RecursionError escapes yaml.safe_load; same fix as above."""
    error_of(write(tmp_path, "S: " + "[" * 3000 + "]" * 3000 + "\nR: [5]\nC: [5]\n"))


def test_huge_integer_metres_is_a_garage_error(tmp_path):
    """float(10**400) raises OverflowError in _vector. Fix: convert with
    `try: f = float(v) except OverflowError: raise GarageError(f"{key}[{k}]: number too large", where)`
    and use f for the finite and range checks."""
    assert yaml_error(tmp_path, R="[5, " + "9" * 400 + "]").startswith("R[1]: ")


def test_plan_from_lists_huge_integer_in_S_is_a_garage_error():
    """The value message formats int(v): past 4300 digits str() raises ValueError. Fix in _matrix: print
    large values abbreviated, e.g. `shown = int(v) if abs(int(v)) < 10**6 else "out of range"`."""
    with pytest.raises(GarageError, match="S row 0, column 1"):
        plan_from_lists([[2, 10**5000]], [5], [5, 5], "big")


# --- plan_from_lists directly -----------------------------------------------------------------------

def test_plan_from_lists_accepts_numpy_arrays():
    plan = plan_from_lists(np.array([[2, 1, 3]]), np.array([6.0]), np.array([5.0, 5.0, 5.0]), "np")
    assert plan.shape == (1, 3) and plan.source == "<memory>"


def test_plan_from_lists_names_its_place():
    with pytest.raises(GarageError, match=r"^conf\.plan: no entrance"):
        plan_from_lists([[0]], [5], [5], "x", where="conf.plan")


@pytest.mark.parametrize("cell, shown", [
    ("'" + "w" * 58 + "'", repr("w" * 58)),  # a repr of exactly 60 characters is shown whole
    ("'" + "w" * 59 + "'", repr("w" * 59)[:57] + "..."),  # 61: cut to 57 and "..."
    ("[1, 2]", "a list"),
    ("{a: 1}", "a dict"),
])
def test_bad_values_are_shown_short_in_the_message(tmp_path, cell, shown):
    path = tmp_path / "p.yaml"
    path.write_text(f"S: [[2, {cell}, 3], [0, 0, 0]]\nR: [6, 5]\nC: [3, 3, 3]\n")
    with pytest.raises(GarageError) as err:
        load_plan(path)
    assert f"S row 0, column 1: {shown} is not an integer" in str(err.value)


def test_csv_comment_lines_are_skipped_even_when_indented(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("  # a note\n,3,3,3\n6,2,1,3\n5,0,0,0\n")
    assert load_plan(path).S.tolist() == [[2, 1, 3], [0, 0, 0]]


def test_cell_geometry_of_a_small_plan():
    """Row 0 is the north side: y grows upwards from the south edge, x with the column index."""
    plan = plan_from_lists([[2, 1, 3], [0, 0, 0]], [6.0, 5.0], [3.0, 4.0, 2.0], "small")
    assert plan.cell_rect(0, 1) == (3.0, 5.0, 7.0, 11.0)
    assert plan.cell_center(0, 1) == (5.0, 8.0)
    assert plan.cell_center(1, 2) == (8.0, 2.5)
    assert plan.vertex(1, 1) == (3.0, 5.0)
    assert plan.cell_at(5.0, 8.0) == (0, 1) and plan.cell_at(8.5, 1.0) == (1, 2)
