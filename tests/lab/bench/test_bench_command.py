"""``eaglemission bench`` on tiny generated data (and one short real sequence)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from saliency_datasets import make_box_dataset, make_mask_dataset

from eaglemission.cli import main


def test_bench_on_generated_dataset(tmp_path, rng, capsys):
    data = make_mask_dataset(tmp_path / "data", rng)
    out, maps = tmp_path / "out", tmp_path / "maps"
    rc = main(["bench", "--data", str(data), "--detectors", "ft,centre_prior,sr",
               "--params", "ft:normalization=minmax", "--out", str(out),
               "--save-maps", str(maps), "--no-progress"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert set(res["detectors"]) == {"ft", "centre_prior", "sr"}
    ft = res["detectors"]["ft"]
    assert ft["params"] == {"normalization": "minmax"}
    assert ft["overall"]["frames"] == 8 and set(ft["sequences"]) == {"alpha", "beta"}
    # a saturated square on flat noise: FT nails it, the centre prior does not
    assert ft["overall"]["max_f"] > 0.9 and ft["overall"]["auc"] > 0.95
    assert ft["overall"]["max_f"] > res["detectors"]["centre_prior"]["overall"]["max_f"]
    assert len(ft["curves"]["precision"]) == 256
    # the square is the best region in every frame
    assert ft["box"]["overall"]["best_on_mask"] == 1.0
    assert ft["box"]["overall"]["mask_frames"] == 8
    assert res["detectors"]["centre_prior"]["detections_per_frame"] == 1.0
    text = (out / "results.md").read_text()
    assert "| ft |" in text and "| alpha |" in text and "max F / SR" in text
    for png in ("pr_curves.png", "roc_curves.png"):
        assert cv2.imread(str(out / png)) is not None
    saved = sorted(maps.glob("*/*/*.png"))
    assert len(saved) == 3 * 2 * 4
    m = cv2.imread(str(maps / "ft" / "alpha" / "00000.png"), cv2.IMREAD_UNCHANGED)
    assert m.dtype == np.uint8 and m.shape == (48, 64) and m.max() == 255
    assert "| ft |" in capsys.readouterr().out


def test_bench_variant_label_and_sequence_subset(tmp_path, rng):
    data = make_mask_dataset(tmp_path / "data", rng)
    out = tmp_path / "out"
    rc = main(["bench", "--data", str(data), "--detectors", "ft,ft@minmax", "--params",
               "ft@minmax:normalization=minmax", "--sequences", "beta", "--max-frames", "2",
               "--out", str(out), "--no-progress"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert res["detectors"]["ft@minmax"]["params"] == {"normalization": "minmax"}
    assert res["detectors"]["ft"]["params"] == {}
    assert res["sequences"] == {"beta": {"frames": 2, "scored": 2, "annotation": "masks"}}


@pytest.mark.parametrize("argv, message", [
    (["--data", "{tmp}/nope"], "folder not found"),
    (["--data", "{tmp}/empty"], "no sequence folder"),
    (["--data", "{tmp}/noframes"], "no frames"),
    (["--data", "{tmp}/nogt"], "no ground truth"),
    (["--data", "{tmp}/data", "--detectors", "nosuch"], "no detector plugin named 'nosuch'"),
    (["--data", "{tmp}/data", "--sequences", "gamma"], "gamma not found"),
    (["--data", "{tmp}/data", "--detectors", "ft", "--params", "ft:bogus=1"], "unknown key"),
])
def test_bench_errors_are_clear(tmp_path, rng, capsys, argv, message):
    make_mask_dataset(tmp_path / "data", rng, seqs=("alpha",), n=1)
    (tmp_path / "empty").mkdir()
    (tmp_path / "noframes" / "s" / "frames").mkdir(parents=True)
    make_mask_dataset(tmp_path / "nogt", rng, seqs=("s",), n=1)
    for p in (tmp_path / "nogt" / "s" / "gt").iterdir():
        p.unlink()
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    rc = main(["bench", *argv, "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert message in err and "Traceback" not in err


def test_bench_one_real_sequence(davis, tmp_path):
    out = tmp_path / "out"
    rc = main(["bench", "--data", str(davis), "--detectors", "sr,centre_prior",
               "--sequences", "blackswan", "--max-frames", "6", "--out", str(out),
               "--no-progress"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())["detectors"]
    for label in ("sr", "centre_prior"):
        o = res[label]["overall"]
        assert o["frames"] == 6
        assert 0.5 < o["auc"] <= 1.0 and 0.0 < o["max_f"] < 1.0 and 0.0 < o["mae"] < 0.5


def test_bench_on_a_box_sequence(tmp_path, rng, capsys):
    data = make_box_dataset(tmp_path / "data", rng)
    out = tmp_path / "out"
    rc = main(["bench", "--data", str(data), "--detectors", "ft,centre_prior",
               "--params", "ft:normalization=minmax", "--out", str(out), "--no-progress"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert res["sequences"] == {"set/seq": {"frames": 10, "scored": 10, "annotation": "boxes"}}
    ft = res["detectors"]["ft"]["box"]["overall"]
    assert ft["frames"] == 10 and ft["target_frames"] == 9
    assert ft["best_on_target"] == 1.0 and ft["peak_on_target"] == 1.0
    assert ft["mean_iou"] > 0.8
    # the target-free frame: min-max stretches the noise, 5 regions (the cap), all false
    assert ft["false_per_frame"] == pytest.approx(5 / 10)
    cp = res["detectors"]["centre_prior"]["box"]["overall"]
    assert cp["frames_with_detection"] == 1.0 and cp["best_on_target"] < 0.7
    assert "overall" not in res["detectors"]["ft"]  # no masks: no max F / AUC
    text = (out / "results.md").read_text()
    assert "| set/seq | 9/10 |" in text and "max F / SR" not in text
    assert cv2.imread(str(out / "box_on_target.png")) is not None
    assert not (out / "pr_curves.png").exists()
    # zero-based reading shifts the boxes by one pixel: still on target
    rc = main(["bench", "--data", str(data), "--detectors", "ft", "--params",
               "ft:normalization=minmax", "--box-origin", "0", "--sequences", "seq",
               "--out", str(tmp_path / "o0"), "--no-progress"])
    res0 = json.loads((tmp_path / "o0" / "results.json").read_text())
    assert rc == 0 and res0["detectors"]["ft"]["box"]["overall"]["best_on_target"] == 1.0
    assert res0["detectors"]["ft"]["box"]["overall"]["mean_iou"] < ft["mean_iou"]


def test_bench_first_frame_target_image_skips_the_head(tmp_path, rng):
    data = make_box_dataset(tmp_path / "data", rng, n=20)
    out = tmp_path / "out"
    rc = main(["bench", "--data", str(data), "--detectors", "ft", "--params",
               "ft:normalization=minmax", "--target-image", "first-frame", "--out", str(out),
               "--no-progress"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    b = res["detectors"]["ft"]["box"]["overall"]
    # first 10 % (2 frames) not scored; frame 3 has no target
    assert b["frames"] == 18 and b["target_frames"] == 17
    assert res["target_image"] == "first-frame" and res["unscored_head"] == 0.1
    # the same frames without the image
    rc = main(["bench", "--data", str(data), "--detectors", "ft", "--params",
               "ft:normalization=minmax", "--unscored-head", "0.1", "--out",
               str(tmp_path / "o2"), "--no-progress"])
    res2 = json.loads((tmp_path / "o2" / "results.json").read_text())
    assert res2["detectors"]["ft"]["box"]["overall"]["frames"] == 18


def test_bench_box_file_errors(tmp_path, rng, capsys):
    data = make_box_dataset(tmp_path / "data", rng, n=3)
    box_file = data / "set" / "seq" / "boxes.txt"
    box_file.write_text("1,1,4,4\n1,1,4,4\n")
    rc = main(["bench", "--data", str(data), "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 2 and "2 box line(s) for 3 frame(s)" in capsys.readouterr().err
    box_file.write_text("1,1,4\n1,1,4,4\n1,1,4,4\n")
    rc = main(["bench", "--data", str(data), "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 2 and "boxes.txt:1: expected x,y,w,h" in capsys.readouterr().err
    box_file.write_text("1,1,4,4\n1,1,4,4\n1,1,4,4\n")
    rc = main(["bench", "--data", str(data), "--target-image", str(tmp_path / "nope.png"),
               "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 2 and "--target-image" in capsys.readouterr().err



def _table(text: str, column: str) -> dict[str, str]:
    """``{first cell: cell of column}`` of the markdown table whose header has ``column``."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if column in cells:
            k = cells.index(column)
            rows = {}
            for row in lines[i + 2:]:
                if not row.startswith("|"):
                    break
                r = [c.strip() for c in row.strip().strip("|").split("|")]
                rows[r[0]] = r[k]
            return rows
    raise AssertionError(f"no table with a column {column!r}")


def test_bench_tables_agree_on_the_best_detection_on_the_mask(tmp_path, capsys):
    """A ring whose hole holds the frame's centre: the centre prior's one detection is inside
    the ring's (grown) box but never on the mask. Both tables give the one figure, from the
    box metrics: 0 % on the mask, 100 % on target."""
    root = tmp_path / "data"
    w, h = 64, 48
    for name in ("ring",):
        (root / name / "frames").mkdir(parents=True)
        (root / name / "gt").mkdir()
        for i in range(3):
            img = np.full((h, w, 3), 90, np.uint8)
            gt = np.zeros((h, w), np.uint8)
            gt[12:37, 20:45] = 255
            gt[18:31, 26:39] = 0  # the hole, around the centre (31.5, 23.5)
            img[gt > 0] = (40, 200, 240)
            cv2.imwrite(str(root / name / "frames" / f"{i:05d}.png"), img)
            cv2.imwrite(str(root / name / "gt" / f"{i:05d}.png"), gt)
    out = tmp_path / "out"
    rc = main(["bench", "--data", str(root), "--detectors", "centre_prior,ft", "--params",
               "ft:normalization=minmax", "--out", str(out), "--no-progress"])
    assert rc == 0
    text = (out / "results.md").read_text()
    res = json.loads((out / "results.json").read_text())["detectors"]
    curve_part, box_part = text.split("Box metrics", 1)
    assert "max F / SR" in curve_part
    curve_fig = _table(curve_part, "best detection on the mask")
    box_fig = _table(box_part, "best detection on the mask")
    assert curve_fig == box_fig and set(curve_fig) == {"centre_prior", "ft"}
    assert curve_fig["centre_prior"] == "0.0%"
    assert _table(box_part, "best detection on target")["centre_prior"] == "100.0%"
    assert res["centre_prior"]["box"]["overall"]["best_on_mask"] == 0.0
    assert res["centre_prior"]["box"]["overall"]["best_on_target"] == 1.0
    assert "best_detection_on_gt" not in res["centre_prior"]

