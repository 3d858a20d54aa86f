"""The plan map PNG (drawn to scale, not mirrored, every cell type visible) and the `python -m garage_exp.plan`
command line."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from PIL import Image
from conftest import run_module

from garage_exp.core.errors import GarageError
from garage_exp.core.paths import PLANS_DIR, PROJECT_ROOT
from garage_exp.plan import classify, load_plan, plan_from_lists
from garage_exp.plan.draw import PILLAR_COLOUR, STYLE, _style_key, draw_map

SHIPPED = sorted(p for p in PLANS_DIR.iterdir() if p.suffix in (".yaml", ".yml", ".csv"))


def rgb(hex_colour: str) -> tuple[int, int, int]:
    return tuple(int(hex_colour[k:k + 2], 16) for k in (1, 3, 5))


def packed(image: np.ndarray) -> np.ndarray:
    """Each RGB pixel as one integer 0xRRGGBB: a colour compared or counted in one pass over a 2-megapixel map
    (np.unique over rows of three took seconds)."""
    image = image.astype(np.uint32)
    return image[..., 0] << 16 | image[..., 1] << 8 | image[..., 2]


def pixels_of(image: np.ndarray, hex_colour: str) -> np.ndarray:
    """(row, column) of every pixel with exactly this colour."""
    r, g, b = rgb(hex_colour)
    return np.argwhere(packed(image) == (r << 16 | g << 8 | b))


def render(classified, tmp_path, name="map.png") -> np.ndarray:
    path = draw_map(classified, tmp_path / name)
    assert path == tmp_path / name and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return np.asarray(Image.open(path).convert("RGB"))


@pytest.mark.parametrize("plan_path", SHIPPED, ids=lambda p: p.name)
def test_map_of_every_shipped_plan_shows_every_cell_type(plan_path, tmp_path):
    classified = classify(load_plan(plan_path))
    image = render(classified, tmp_path)
    assert image.shape[0] > 500 and image.shape[1] > 700
    assert len(np.unique(packed(image))) > 20, "blank or nearly blank map"
    plan = classified.plan
    area: dict = {}
    for cell in classified.all_cells():
        x0, y0, x1, y1 = plan.cell_rect(cell.i, cell.j)
        area[_style_key(cell)] = area.get(_style_key(cell), 0.0) + (x1 - x0) * (y1 - y0)
    density = {}
    for key, metres2 in area.items():
        count = len(pixels_of(image, STYLE[key][1]))
        assert count > 100, f"{key} is not visible on the map"
        if not STYLE[key][2]:  # hatching hides part of the fill colour
            density[key] = count / metres2
    # Drawn to scale: every unhatched type covers the same number of pixels per square metre (arrows, grid
    # lines and the legend swatch disturb this a little, and a lot for a type of a few cells on a big plan's
    # map: the entrance of a 26 x 30-cell garage; so types under 1 % of the plan's area are left out).
    total = sum(area.values())
    even = [d for key, d in density.items() if area[key] >= 0.01 * total]
    assert len(even) >= 2 and max(even) / min(even) < 1.15, density
    assert len(pixels_of(image, PILLAR_COLOUR)) > 4 * len(classified.pillars)


def test_map_is_seen_from_above_not_mirrored(tmp_path):
    """research.yaml has its entrance in row 0 near the west wall and its exit in the last row near the east
    wall: on the map the entrance is top left of the exit (x right, y up)."""
    image = render(classify(load_plan(PLANS_DIR / "research.yaml")), tmp_path)
    entrance = pixels_of(image, STYLE["entrance", ""][1])
    exit_ = pixels_of(image, STYLE["exit", ""][1])
    # The legend swatches are the few pixels far right: take the median, which lies in the plan.
    (er, ec), (xr, xc) = np.median(entrance, axis=0), np.median(exit_, axis=0)
    assert er < xr and ec < xc


def test_map_of_a_200_cell_garage(tmp_path):
    """About 60 x 60 m in 220 cells (2.5 m bay cells): every type still shows up and pillars are drawn."""
    m, n = 11, 20
    S = np.zeros((m, n), int)
    S[[1, 4, 7, 10], 1:19] = 1
    S[1:11, [1, 10, 18]] = 1
    S[4, 0], S[10, 19], S[0, 0], S[0, 19] = 2, 3, -1, -1
    R = [5.0, 6.0, 5.0, 5.0, 6.0, 5.0, 5.0, 6.0, 5.0, 5.0, 6.0]
    C = [5.0, 6.0] + [2.5] * 8 + [6.0] + [2.5] * 7 + [6.0, 5.0]
    classified = classify(plan_from_lists(S.tolist(), R, C, "big"))
    image = render(classified, tmp_path)
    for key in {_style_key(c) for c in classified.all_cells()}:
        assert len(pixels_of(image, STYLE[key][1])) > 100, key
    assert len(pixels_of(image, PILLAR_COLOUR)) > 4 * len(classified.pillars)


def test_map_of_a_one_cell_plan(tmp_path):
    image = render(classify(plan_from_lists([[2]], [6.0], [6.0], "one")), tmp_path)
    assert len(pixels_of(image, STYLE["entrance", ""][1])) > 1000


def test_map_with_a_title_and_new_folders(tmp_path):
    path = draw_map(classify(load_plan(PLANS_DIR / "tiny.yaml")), tmp_path / "a" / "b" / "m.png", title="Level B2")
    assert path.is_file()


def test_map_to_an_impossible_place_is_a_garage_error(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(GarageError, match="cannot write the map"):
        draw_map(classify(load_plan(PLANS_DIR / "tiny.yaml")), tmp_path / "file" / "m.png")


# --- command line -------------------------------------------------------------------------------------

def cli(*args: str, cwd) -> subprocess.CompletedProcess:
    """`python -m garage_exp.plan ARGS`, in this process (conftest.run_module: runpy as -m, exit code, stdout and
    stderr captured); the command in a process of its own is test_command_exits' (its SIGTERM)."""
    return run_module("garage_exp.plan", [*map(str, args)], cwd, {"MPLBACKEND": "Agg"})


@pytest.mark.parametrize("content", ["S: [[2, 1]]\nR: [5]\n", b"\x00\xff\xfe junk \x89PNG"],
                         ids=["missing-C", "binary"])
def test_cli_bad_file_exits_2_with_one_line(tmp_path, content):
    bad = tmp_path / "bad.yaml"
    bad.write_bytes(content if isinstance(content, bytes) else content.encode())
    for command in ("check", "map"):
        result = cli(command, bad, cwd=tmp_path)
        assert result.returncode == 2
        assert result.stdout == ""
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and str(bad) in lines[0] and "Traceback" not in result.stderr
    assert not list(tmp_path.glob("*.png"))


def test_cli_check_summarises_the_plan(tmp_path):
    path = PLANS_DIR / "realistic.yaml"
    classified = classify(load_plan(path))
    result = cli("check", path, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "8 x 9 cells" in out and "57.6 x 43.0 m" in out
    assert f"pillars: {len(classified.pillars)}" in out
    assert "crossroads 1" in out and "t_junction 2" in out and "type3 27" in out


def test_cli_map_writes_the_png(tmp_path):
    out = tmp_path / "maps" / "research.png"
    result = cli("map", PLANS_DIR / "research_csv.csv", "-o", out, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert out.read_bytes()[:4] == b"\x89PNG" and result.stdout.strip() == str(out)
    default = cli("map", PLANS_DIR / "tiny.yaml", cwd=tmp_path)
    assert default.returncode == 0 and (tmp_path / "tiny_map.png").is_file()


def test_cli_generate_writes_the_shipped_generated_garages(tmp_path):
    """The plan generator lives with the plans (`python -m garage_exp.plan generate`, issue 32 item 6) and the
    shipped plans/garage*.yaml are its output, byte for byte; each loads and classifies."""
    from garage_exp.plan.__main__ import main

    assert main(["generate", "-o", str(tmp_path)]) == 0
    written = sorted(tmp_path.glob("*.yaml"))
    assert [p.name for p in written] == ["garage13x15.yaml", "garage26x30.yaml", "garage39x45.yaml"]
    for path in written:
        assert path.read_bytes() == (PLANS_DIR / path.name).read_bytes()
        assert "python -m garage_exp.plan generate" in path.read_text().splitlines()[3]
    assert classify(load_plan(written[0])).plan.shape == (13, 15)


def test_makefile_map_target_uses_this_cli():
    assert "python -m garage_exp.plan map" in (PROJECT_ROOT / "Makefile").read_text()


@pytest.mark.parametrize("span, length", [(50.0, 10.0), (100.0, 20.0), (30.0, 5.0), (7.0, 1.0), (400.0, 100.0),
                                          (0.6, 0.1), (0.0, 1e-9)])
def test_scale_bar_is_a_round_length_near_a_fifth_of_the_span(span, length):
    from garage_exp.plan.draw import _nice_length

    assert _nice_length(span) == pytest.approx(length)
