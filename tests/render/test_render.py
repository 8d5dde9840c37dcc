"""Offscreen rendering: real EGL renders, checked on their pixels."""

from __future__ import annotations

import colorsys
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("pyrender")
imageio = pytest.importorskip("imageio.v2")

from conftest import PHENO4D, pheno4d  # noqa: E402

from torch4dtree import Trees, TreeSequence  # noqa: E402
from torch4dtree.io import LoadOptions, read_sequence  # noqa: E402
from torch4dtree.render import (  # noqa: E402
    GL_PACKAGES,
    LABEL_PALETTE,
    LAYER_COLORS,
    branch_colors,
    render_grid,
    render_sequence,
    render_trees,
    save_image,
    save_video,
    tree_meshes,
)

SIZE = 128


def line(a, b, n: int = 20) -> np.ndarray:
    return np.linspace(np.asarray(a, float), np.asarray(b, float), n)


def four_layer_tree(labels=None) -> Trees:
    """A main stem with a side branch, a sub-branch and a sub-sub-branch, spread out in the x-z plane."""
    main = line([0, 0, 0], [0, 0, 10])
    side = line([0, 0, 4], [5, 0, 7])
    sub = line([2.5, 0, 5.5], [2.5, 0, 9])
    subsub = line([2.5, 0, 7.5], [-1.5, 0, 9.5])
    return Trees.from_branches([[main, side, sub, subsub]], [[-1, 0, 1, 2]], T=32, labels=labels)


def hue_of(rgb) -> float:
    r, g, b = (np.asarray(rgb, float) / 255.0).tolist()
    return colorsys.rgb_to_hsv(r, g, b)[0] * 360.0


def hue_count(img: np.ndarray, rgb, tol: float = 8.0) -> int:
    """Pixels whose hue is within ``tol`` degrees of ``rgb``'s (hue survives shading and fading to white)."""
    x = img.reshape(-1, 3).astype(float) / 255.0
    mx, mn = x.max(1), x.min(1)
    sat = (mx - mn) / np.maximum(mx, 1e-9)
    keep = sat > 0.3
    hsv = np.array([colorsys.rgb_to_hsv(*p)[0] * 360.0 for p in x[keep]]) if keep.any() else np.zeros(0)
    d = np.abs((hsv - hue_of(rgb) + 180) % 360 - 180)
    return int((d < tol).sum())


def plant_mask(img: np.ndarray) -> np.ndarray:
    """``(..., H, W)`` pixels that are not the white background."""
    return (img < 250).any(-1)


def border(mask: np.ndarray) -> np.ndarray:
    """``(n,)`` plant pixels on the outermost ring of each ``(n, H, W)`` mask."""
    return mask[:, 0].sum(-1) + mask[:, -1].sum(-1) + mask[:, :, 0].sum(-1) + mask[:, :, -1].sum(-1)


@pytest.fixture(scope="module")
def maize() -> TreeSequence:
    return read_sequence(pheno4d("swc", "Maize02"), LoadOptions(T=32, repair=True)).sequence


def growing_sequence(n: int = 4) -> TreeSequence:
    """A synthetic plant that grows: taller every frame, a new side branch every frame."""
    trees = []
    for k in range(n):
        h = 4.0 + 2.0 * k
        brs, par = [line([0, 0, 0], [0.3 * k, 0, h])], [-1]
        for j in range(k):
            z = 1.0 + j * 1.5
            sign = 1 if j % 2 else -1
            brs.append(line([0.3 * k * z / h, 0, z], [sign * (2 + k - j), 0.5, z + 1.5]))
            par.append(0)
        trees.append(Trees.from_branches([brs], [par], T=32))
    return TreeSequence(Trees.cat(trees), torch.tensor([0.0, 1.0, 3.0, 7.0][:n]), "grow")


# ------------------------------------------------------------------------------------------ frames
def test_tree_pixels_layers_and_white_border():
    img = render_trees(four_layer_tree(), size=SIZE)
    assert img.shape == (1, SIZE, SIZE, 3) and img.dtype == np.uint8
    mask = plant_mask(img)
    assert border(mask)[0] == 0, "the plant touches the frame"
    assert mask[0, 8:-8, 8:-8].sum() > 200
    assert (img[0, 0] == 255).all()  # white background
    for d in range(4):
        assert hue_count(img[0], LAYER_COLORS[d]) > 20, f"layer {d} colour missing"


def test_layer_colours_absent_when_layers_absent():
    main = line([0, 0, 0], [0, 0, 10])
    two = Trees.from_branches([[main, line([0, 0, 4], [5, 0, 7])]], [[-1, 0]], T=32)
    img = render_trees(two, size=SIZE)[0]
    assert hue_count(img, LAYER_COLORS[0]) > 20 and hue_count(img, LAYER_COLORS[1]) > 20
    assert hue_count(img, LAYER_COLORS[2]) == 0 and hue_count(img, LAYER_COLORS[3]) <= 2


def test_renders_are_deterministic_and_views_differ():
    trees = four_layer_tree()
    a = render_trees(trees, size=SIZE, view="side")
    b = render_trees(trees, size=SIZE, view="side")
    assert np.array_equal(a, b)
    assert not np.array_equal(a, render_trees(trees, size=SIZE, view="top"))


def test_scale_invariance_and_null_branches():
    # radii and camera follow the scene's size: a 1 um plant and a 10 m plant look the same
    tree = four_layer_tree()
    ref = render_trees(tree, size=SIZE)
    for factor in (1e-4, 1e3):
        other = render_trees(tree.with_points(tree.points * factor), size=SIZE)
        assert (np.abs(other.astype(int) - ref).max(-1) > 24).mean() < 0.002
    # a null branch (zero length, as in registered trees) is not drawn
    pts = torch.cat([tree.points, tree.points[1:2, :1].expand(1, tree.T, 3)])
    padded = Trees(pts, torch.tensor([-1, 0, 1, 2, 1]), torch.cat([tree.s, tree.s[2:3]]), torch.tensor([5]),
                   torch.full((5,), -1))
    assert np.array_equal(render_trees(padded, size=SIZE), ref)


def test_label_colours_match_for_equal_labels():
    # main label 3; side branch and its sub-branch both label 5; the last branch unlabelled (-1)
    trees = four_layer_tree(labels=[[3, 5, 5, -1]])
    cols = branch_colors(trees, "label")
    assert (cols[1] == cols[2]).all() and not (cols[0] == cols[1]).all()
    img = render_trees(trees, size=SIZE, color="label")[0]
    assert hue_count(img, LABEL_PALETTE[3]) > 20
    # both label-5 branches (side goes right, sub-branch goes up) carry the same colour
    right = img[:, SIZE // 2 + 10:]
    assert hue_count(right, LABEL_PALETTE[5]) > 20 and hue_count(img[: SIZE // 3], LABEL_PALETTE[5]) > 5
    x = img.reshape(-1, 3).astype(int)
    grey = (x.max(1) - x.min(1) < 12) & (x.max(1) < 235)
    assert grey.sum() > 10, "the unlabelled branch should be grey"
    assert hue_count(img, LAYER_COLORS[0], tol=4) == 0  # no layer red in a label rendering


def test_tube_mesh_volume_and_outward_normals():
    opts = dict(radius=0.05, taper=0.0, sides=12)
    cyl = Trees.from_branches([[line([0, 0, 0], [0, 0, 10], 2)]], [[-1]], T=16)
    (mesh,) = tree_meshes(cyl, **opts)
    r, K = 0.05 * 10, 12
    assert mesh.volume == pytest.approx(K / 2 * np.sin(2 * np.pi / K) * r**2 * 10, rel=1e-6)
    ring = mesh.vertices[: 16 * K]
    radial = ring - np.c_[np.zeros((len(ring), 2)), ring[:, 2]]
    assert (np.einsum("ij,ij->i", radial, mesh.vertex_normals[: 16 * K]) > 0).all()
    assert len(tree_meshes(four_layer_tree())[0].vertices) == 4 * (32 * 8 + 2)


# ---------------------------------------------------------------------------------------- videos
def test_sequence_video_frames_and_decoding(tmp_path: Path):
    seq = growing_sequence()
    frames = render_sequence(seq, n_frames=6, size=96, caption=True)
    assert frames.shape == (6, 96, 96, 3)
    # the plant grows: more plant pixels at the end than at the start
    assert plant_mask(frames[-1]).sum() > plant_mask(frames[0]).sum()
    for suffix in (".mp4", ".gif"):
        path = save_video(tmp_path / f"grow{suffix}", frames, fps=3)
        back = imageio.mimread(path)
        assert len(back) == 6 and back[0].shape[:2] == (96, 96)
    # odd sizes are padded to even ones for H.264
    odd = render_sequence(seq, size=(75, 61))
    assert odd.shape == (4, 61, 75, 3)
    back = imageio.mimread(save_video(tmp_path / "odd.mp4", odd, fps=2))
    assert len(back) == 4 and back[0].shape[:2] == (62, 76)


def test_camera_frames_the_whole_sequence(maize: TreeSequence):
    for view in ("front", "orbit"):
        frames = render_sequence(maize, size=SIZE, view=view)
        mask = plant_mask(frames)
        assert (border(mask) == 0).all(), f"{view}: plant pixels on the frame border"
        assert mask[0].sum() < mask[-1].sum(), "growth must show (fixed camera)"
        # the camera is tight: the last day fills most of the frame in one direction
        ys, xs = np.nonzero(mask[-1])
        assert max(np.ptp(ys), np.ptp(xs)) > 0.7 * SIZE
    top = render_sequence(maize[[len(maize) - 1]], size=SIZE, view="top")
    assert border(plant_mask(top))[0] == 0


def test_grid_image_and_video():
    seq = growing_sequence(3)
    batch = Trees.cat([four_layer_tree(), four_layer_tree()])
    img = render_grid([seq, batch], row_labels=["grow", "pair"], col_labels=["a", "b", "c"], title="Grid", size=64)
    assert img.ndim == 3 and img.shape[0] > 2 * 64 and img.shape[1] > 3 * 64
    assert (img[-64:, -64:] == 255).all()  # the short row is padded with a white cell
    vid = render_grid([seq, batch], row_labels=["grow", "pair"], video=True, n_frames=5, size=64)
    assert vid.shape[0] == 5 and vid.shape[2] == 128 and 64 < vid.shape[1] < 2 * 64  # a label strip above the cells
    with pytest.raises(ValueError):
        render_grid([seq], col_labels=["only one"], size=64)


def test_saving_refuses_to_overwrite(tmp_path: Path):
    img = render_trees(four_layer_tree(), size=64)
    p = save_image(tmp_path / "t.png", img[0])
    before = p.read_bytes()
    with pytest.raises(FileExistsError):
        save_image(p, np.zeros_like(img[0]))
    assert p.read_bytes() == before
    save_image(p, np.zeros_like(img[0]), overwrite=True)
    assert p.read_bytes() != before
    frames = np.repeat(img, 2, axis=0)
    for suffix in (".gif", ".mp4"):
        v = save_video(tmp_path / f"v{suffix}", frames)
        data = v.read_bytes()
        with pytest.raises(FileExistsError):
            save_video(v, frames[:1])
        assert v.read_bytes() == data
        save_video(v, frames[:1], overwrite=True)
    assert sorted(q.name for q in tmp_path.iterdir()) == ["t.png", "v.gif", "v.mp4"]  # no temporaries left


# ------------------------------------------------------------------------------------------- CLI
def cli(*argv: str) -> int:
    from torch4dtree.cli import main

    return main(["render", *argv])


def test_cli_tree_sequence_and_dataset(tmp_path: Path, capsys):
    folder = pheno4d("swc", "Maize02")
    tree_file = sorted(folder.glob("*.swc"))[-1]
    out = tmp_path / "tree.png"
    assert cli(str(tree_file), "--out", str(out), "--size", "96", "--T", "16") == 0
    assert imageio.imread(out).shape == (96, 96, 3)
    assert cli(str(tree_file), "--out", str(out), "--size", "96") == 2  # refuses to overwrite
    assert "exists" in capsys.readouterr().err
    assert cli(str(tree_file), "--out", str(out), "--size", "96", "--overwrite") == 0
    gif = tmp_path / "seq.gif"
    assert cli(str(folder), "--out", str(gif), "--size", "80", "--frames", "3", "--repair", "--T", "16",
               "--no-interpolate") == 0
    assert len(imageio.mimread(gif)) == 3
    row = tmp_path / "row.png"
    assert cli(str(folder), "--out", str(row), "--size", "64", "--repair", "--T", "16") == 0
    assert imageio.imread(row).shape[1] == 6 * 64  # one column per day
    data = tmp_path / "data"
    data.mkdir()
    for name in ("Maize02", "Maize04"):
        (data / name).symlink_to(PHENO4D / "swc" / name)
    grid = tmp_path / "grid.png"
    assert cli(str(data), "--out", str(grid), "--size", "48", "--view", "side", "--repair", "--T", "16") == 0
    h, w, _ = imageio.imread(grid).shape
    assert h >= 2 * 48 and w > 7 * 48
    assert cli(str(tmp_path / "nothing"), "--out", str(tmp_path / "x.png")) == 2


def test_missing_egl_gives_a_clear_error():
    # hide libEGL from PyOpenGL in a fresh interpreter: the error must name the packages to install
    code = (
        "import ctypes.util as u\n"
        "f = u.find_library\n"
        "u.find_library = lambda n: None if n == 'EGL' else f(n)\n"
        "from torch4dtree import Trees\n"
        "from torch4dtree.render import render_trees\n"
        "import numpy as np\n"
        "t = Trees.from_branches([[np.array([[0, 0, 0], [0, 0, 1.0]])]], [[-1]], T=4)\n"
        "try:\n"
        "    render_trees(t, size=32)\n"
        "except RuntimeError as e:\n"
        "    print('ERR', e)\n"
    )
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert "ERR" in res.stdout, res.stderr
    assert GL_PACKAGES in res.stdout and "EGL" in res.stdout


def test_import_does_not_need_gl():
    code = "import sys, torch4dtree, torch4dtree.render; print('pyrender' in sys.modules, 'OpenGL' in sys.modules)"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.stdout.split() == ["False", "False"], res.stderr


def test_register_picture_colours_matched_branches_alike(tmp_path: Path):
    """``torch4dtree register A B --image``: A's side branches point +x, +y, -x at s = 0.3, 0.5, 0.7 and B's the
    same directions at 0.5, 0.3, 0.7, so index order pairs the wrong ones. Registration matches by shape; in
    the picture the longest side branch (+x) then has one colour in both trees."""
    from torch4dtree.cli import main
    from torch4dtree.io import write_swc

    T = 16
    u = np.linspace(0.0, 1.0, T)[:, None]
    stem = u * np.array([0.0, 0.0, 3.0])

    def side(s: float, direction: tuple[float, float, float], length: float) -> np.ndarray:
        return np.array([0.0, 0.0, 3.0 * s]) + u * length * np.array(direction)

    arms = {"+x": ((1.0, 0.0, 0.3), 1.0), "+y": ((0.0, 1.0, 0.3), 0.5), "-x": ((-1.0, 0.0, 0.3), 0.7)}
    paths = []
    for name, order in (("a", ("+x", "+y", "-x")), ("b", ("+y", "+x", "-x"))):
        branches = [stem] + [side(s, *arms[k]) for s, k in zip((0.3, 0.5, 0.7), order)]
        tree = Trees.from_branches([branches], [[-1, 0, 0, 0]], T=T, dtype=torch.float64)
        paths.append(write_swc(tmp_path / f"{name}.swc", tree))
    out = tmp_path / "pair.png"
    assert main(["register", str(paths[0]), str(paths[1]), "--T", str(T), "--image", str(out), "--steps", "2"]) == 0
    img = imageio.imread(out)[..., :3]
    halves = img[:, : img.shape[1] // 2], img[:, img.shape[1] // 2:]
    assert all(plant_mask(h).sum() > 50 for h in halves)
    # the side branches' slot colours (the main branch is slot 0): the most frequent one is the +x arm in each
    counts = [[hue_count(h, LABEL_PALETTE[k], tol=4) for k in (1, 2, 3)] for h in halves]
    assert int(np.argmax(counts[0])) == int(np.argmax(counts[1])) and min(max(c) for c in counts) > 20, counts
    assert main(["register", str(paths[0]), str(paths[1]), "--T", str(T), "--image", str(out)]) == 2  # no overwrite


# ------------------------------------------------------------------------------- what a user looks at
def header_ink(img: np.ndarray, top: int) -> np.ndarray:
    """``(top, W)`` dark (text) pixels of the band above the cells."""
    return (img[:top] < 128).all(-1)


def test_long_titles_fit_and_keep_every_line():
    from torch4dtree.render.text import compose

    cells = np.full((1, 2, 64, 64, 3), 200, np.uint8)
    title = "T03_0321_a_seg_with_a_long_name  ->  T03_0324_a_seg\ndistance 38.6 (index order)  ->  28.0 (registered)"
    img = compose(cells, None, ["moving (registered)", "reference"], title)
    top = img.shape[0] - 64
    ink = header_ink(img, top)
    cols = np.nonzero(ink.any(0))[0]
    assert cols.min() > 0 and cols.max() < img.shape[1] - 1, "text cut at an edge"
    rows = np.nonzero(ink.any(1))[0]
    gaps = np.diff(rows) > 1
    assert gaps.sum() >= 2, "expected two title lines and a column-label line"  # separated by blank rows
    one_line = compose(cells, None, None, "short")
    assert one_line.shape[0] < img.shape[0]


def test_video_frames_carry_their_labels_in_the_header():
    seq = growing_sequence()
    frames = render_grid([seq], row_labels=["grow"], video=True, n_frames=3, size=64, frame_labels=["a", "bb", "a"])
    plain = render_grid([seq], video=True, n_frames=3, size=64)
    H = plain.shape[1]
    assert frames.shape[1] > H and np.array_equal(frames[:, -H:], plain)  # labels above the plant, not over it
    top = frames.shape[1] - H
    assert np.array_equal(frames[0, :top], frames[2, :top]) and not np.array_equal(frames[0, :top], frames[1, :top])
    with pytest.raises(ValueError, match="one label per frame"):
        render_grid([seq], video=True, n_frames=3, size=64, frame_labels=["a"])


def test_fitted_panels_are_filled():
    from torch4dtree.render import fit_size

    wide = Trees.from_branches([[line([0, 0, 0], [0, 0, 2]), line([0, 0, 2], [3, 0, 3]), line([0, 0, 2], [-3, 0, 3])]],
                               [[-1, 0, 0]], T=16)
    tall = Trees.from_branches([[line([0, 0, 0], [0, 0, 10]), line([0, 0, 5], [4, 0, 6])]], [[-1, 0]], T=16)
    for tree, landscape in ((wide, True), (tall, False)):
        W, H = fit_size([tree], 128)
        assert max(W, H) == 128 and (W > H) == landscape and W % 2 == H % 2 == 0
        mask = plant_mask(render_trees(tree, size=(W, H))[0])
        ys, xs = np.nonzero(mask)
        fill_x, fill_y = (np.ptp(xs) + 1) / W, (np.ptp(ys) + 1) / H
        assert min(fill_x, fill_y) > 0.5 and max(fill_x, fill_y) > 0.8, (fill_x, fill_y)
        square = plant_mask(render_trees(tree, size=128)[0])
        ys, xs = np.nonzero(square)
        assert min((np.ptp(xs) + 1), (np.ptp(ys) + 1)) / 128 < 0.5  # what the square panel wasted


def test_interpolated_frames_between_scans():
    from torch4dtree.render.interpolate import interpolate_sequence

    seq = growing_sequence()
    labels = torch.cat([torch.arange(n) + 10 for n in seq.frames.num_branches.tolist()])
    seq = TreeSequence(Trees(seq.frames.points.double(), seq.frames.parent, seq.frames.s.double(),
                             seq.frames.num_branches, labels), seq.times, seq.name)
    t = seq.times.double()
    times = torch.tensor([t[0], 0.5, t[1], 2.0, 2.001, t[3]], dtype=torch.float64)
    out = interpolate_sequence(seq, times)
    assert out.num_trees == len(times)
    for k, j in ((0, 0), (2, 1), (5, 3)):  # at a scan time, the scan itself (its registered copy)
        assert torch.allclose(out[k].total_length(), seq.frames[j].total_length(), rtol=1e-9)
        assert torch.allclose(out[k].height(), seq.frames[j].height(), rtol=1e-9)
        assert sorted(out[k].label.tolist()) == sorted(seq.frames[j].label.tolist())
    # between scans: sizes in between, labels from the two scans, and continuous in time
    between = out[1].total_length().item()
    assert seq.frames[0].total_length().item() < between < seq.frames[1].total_length().item()
    assert set(out[3].label.tolist()) <= set(seq.frames[1].label.tolist()) | set(seq.frames[2].label.tolist())
    assert abs(out[3].height().item() - out[4].height().item()) < 1e-2


def test_cli_videos_have_a_time_label_and_interpolated_frames(tmp_path: Path, capsys):
    from torch4dtree.cli import main
    from torch4dtree.io import write_swc

    folder = tmp_path / "grow"
    folder.mkdir()
    seq = growing_sequence(3)
    for k, tree in enumerate(seq.frames.split()):
        write_swc(folder / f"frame_{int(seq.times[k])}.swc", tree.to(torch.float64))
    out = tmp_path / "grow.gif"
    assert main(["render", str(folder), "--out", str(out), "--size", "64", "--T", "16"]) == 0
    assert "wrote" in capsys.readouterr().out
    frames = np.stack(imageio.mimread(out))[..., :3]
    assert len(frames) == 8 * 2 + 1  # 8 frames per interval between scans, evenly spaced in time
    top = frames.shape[1] - 64
    headers = {frames[k, :top].tobytes() for k in range(len(frames))}
    assert len(headers) == len(frames)  # every frame names its own time
    cells = plant_mask(frames[:, top:])
    assert len({c.tobytes() for c in cells}) > 2 * 3  # the plant moves between scans, not only at them
