"""``eaglemission bench`` / ``detect`` on tiny generated data (and one short real sequence)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from eaglemission.detectors.cli_params import UsageError, parse_detector_specs, parse_kv

from eaglemission.cli import main


def _make_dataset(root: Path, rng: np.random.RandomState, seqs=("alpha", "beta"), n=4,
                  size=(64, 48)) -> Path:
    w, h = size
    for s_i, name in enumerate(seqs):
        (root / name / "frames").mkdir(parents=True)
        (root / name / "gt").mkdir()
        for i in range(n):
            img = np.clip(rng.randn(h, w, 3) * 5 + 100, 0, 255).astype(np.uint8)
            gt = np.zeros((h, w), np.uint8)
            u, v = 10 + 4 * i + 3 * s_i, 15
            img[v:v + 12, u:u + 16] = (40, 200, 240)
            gt[v:v + 12, u:u + 16] = 255
            cv2.imwrite(str(root / name / "frames" / f"{i:05d}.jpg"), img)
            cv2.imwrite(str(root / name / "gt" / f"{i:05d}.png"), gt)
    return root


def test_bench_on_generated_dataset(tmp_path, rng, capsys):
    data = _make_dataset(tmp_path / "data", rng)
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
    assert ft["best_detection_on_gt"] == 1.0  # the square is the best region in every frame
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
    data = _make_dataset(tmp_path / "data", rng)
    out = tmp_path / "out"
    rc = main(["bench", "--data", str(data), "--detectors", "ft,ft@minmax", "--params",
               "ft@minmax:normalization=minmax", "--sequences", "beta", "--max-frames", "2",
               "--out", str(out), "--no-progress"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert res["detectors"]["ft@minmax"]["params"] == {"normalization": "minmax"}
    assert res["detectors"]["ft"]["params"] == {}
    assert res["sequences"] == {"beta": {"frames": 2, "scored": 2, "annotation": "masks"}}


def test_parse_detector_specs():
    specs = parse_detector_specs("dtdmi,dtdmi@literal,ft", ["dtdmi:scales=[1, 2]",
                                                            "ft:regions.threshold=otsu"])
    assert [s.label for s in specs] == ["dtdmi", "dtdmi@literal", "ft"]
    assert specs[0].params == {"scales": [1, 2]}
    assert specs[1].params == {"scales": [1, 2], "preset": "literal"}  # preset from the label
    assert specs[2].params == {"regions": {"threshold": "otsu"}}
    # a variant named after a preset keeps it beside params of its own; others are labels
    field, custom = parse_detector_specs("dtdmi@field,dtdmi@mine", [
        "dtdmi@field:downscale=2", "dtdmi@mine:downscale=2"])
    assert field.params == {"downscale": 2, "preset": "field"}
    assert custom.params == {"downscale": 2}
    (other,) = parse_detector_specs("dtdmi@field", ["dtdmi@field:preset=aerial"])
    assert other.params == {"preset": "aerial"}
    with pytest.raises(UsageError, match="no `preset` param"):
        parse_detector_specs("ft@x", [])
    with pytest.raises(UsageError, match="not in --detectors"):
        parse_detector_specs("ft", ["sr:downscale=2"])
    with pytest.raises(UsageError, match="DETECTOR:KEY=VALUE"):
        parse_detector_specs("ft", ["downscale=2"])
    with pytest.raises(UsageError, match="twice"):
        parse_detector_specs("ft,ft", [])
    assert parse_kv(["a.b=1", "a.c=x", "d=true"]) == {"a": {"b": 1, "c": "x"}, "d": True}


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
    _make_dataset(tmp_path / "data", rng, seqs=("alpha",), n=1)
    (tmp_path / "empty").mkdir()
    (tmp_path / "noframes" / "s" / "frames").mkdir(parents=True)
    _make_dataset(tmp_path / "nogt", rng, seqs=("s",), n=1)
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


def test_detect_on_image_folder_and_video(tmp_path, rng, capsys):
    data = _make_dataset(tmp_path / "data", rng, seqs=("alpha",), n=3, size=(96, 72))
    frames = data / "alpha" / "frames"
    out = tmp_path / "out_imgs"
    rc = main(["detect", str(frames), "--detector", "ft", "--out", str(out),
               "--params", "regions.min_area_px=20"])
    assert rc == 0
    jpgs = sorted(out.glob("*.jpg"))
    assert len(jpgs) == 3 and cv2.imread(str(jpgs[0])).shape == (72, 96, 3)
    lines = [json.loads(x) for x in (out / "detections.jsonl").read_text().splitlines()]
    assert len(lines) == 3 and lines[0]["detections"], lines[0]
    c = np.array(lines[0]["detections"][0]["corners_px"])
    assert c.shape == (4, 2) and np.argmin(c.sum(axis=1)) == 0
    assert (out / "overlay.mp4").stat().st_size > 0
    # a video input
    video = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (96, 72))
    for f in sorted(frames.glob("*.jpg")):
        vw.write(cv2.imread(str(f)))
    vw.release()
    rc = main(["detect", str(video), "--detector", "centre_prior", "--out", str(tmp_path / "ov"),
               "--no-video", "--max-frames", "2"])
    assert rc == 0
    assert len(list((tmp_path / "ov").glob("*.jpg"))) == 2


def test_detect_config_file_and_errors(tmp_path, rng, capsys):
    data = _make_dataset(tmp_path / "data", rng, seqs=("alpha",), n=1, size=(96, 72))
    cfg = tmp_path / "mission.yaml"
    cfg.write_text("detector:\n  type: ft\n  params: {normalization: minmax}\n")
    rc = main(["detect", str(data / "alpha" / "frames"), "--config", str(cfg),
               "--out", str(tmp_path / "o1"), "--no-video"])
    assert rc == 0
    # a prior that excludes the 16 x 12 px square: no detection left
    rc = main(["detect", str(data / "alpha" / "frames"), "--detector", "ft", "--params",
               "normalization=minmax", "--min-area-px", "500", "--out", str(tmp_path / "o6"),
               "--no-video"])
    line = json.loads((tmp_path / "o6" / "detections.jsonl").read_text().splitlines()[0])
    assert rc == 0 and line["detections"] == []
    rc = main(["detect", str(data / "alpha" / "frames"), "--detector", "ft", "--params",
               "normalization=minmax", "--aspect-ratio", "1.33", "--aspect-tolerance", "0.1",
               "--out", str(tmp_path / "o7"), "--no-video"])
    line = json.loads((tmp_path / "o7" / "detections.jsonl").read_text().splitlines()[0])
    assert rc == 0 and len(line["detections"]) == 1
    assert line["detections"][0]["size_px"] == pytest.approx([16.0, 12.0])
    rc = main(["detect", str(data / "alpha" / "frames"), "--detector", "ft", "--aspect-ratio",
               "0.5", "--out", str(tmp_path / "o8")])
    assert rc == 2 and "must be >= 1" in capsys.readouterr().err
    rc = main(["detect", str(tmp_path / "missing"), "--detector", "ft", "--out", str(tmp_path / "o2")])
    assert rc == 2 and "not found" in capsys.readouterr().err
    (tmp_path / "emptydir").mkdir()
    rc = main(["detect", str(tmp_path / "emptydir"), "--detector", "ft", "--out", str(tmp_path / "o3")])
    assert rc == 2 and "no images" in capsys.readouterr().err
    rc = main(["detect", str(data / "alpha" / "frames"), "--detector", "nosuch",
               "--out", str(tmp_path / "o4")])
    err = capsys.readouterr().err
    assert rc == 2 and "no detector plugin" in err and "Traceback" not in err
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"not a video")
    rc = main(["detect", str(bad), "--detector", "ft", "--out", str(tmp_path / "o5")])
    assert rc == 2 and "cannot open as a video" in capsys.readouterr().err


def _make_box_dataset(root: Path, rng: np.random.RandomState, n: int = 10,
                      size=(96, 64)) -> Path:
    """``root/set/seq``: a yellow 16 x 12 px square moving right on faint noise, boxes.txt
    1-based, frame 3 without the target (nan)."""
    w, h = size
    seq = root / "set" / "seq"
    (seq / "frames").mkdir(parents=True)
    lines = []
    for i in range(n):
        img = np.clip(rng.randn(h, w, 3) * 1 + 100, 0, 255).astype(np.uint8)
        u, v = 10 + 4 * i, 20
        if i == 3:
            lines.append("nan,nan,nan,nan")
        else:
            img[v:v + 12, u:u + 16] = (40, 200, 240)
            lines.append(f"{u + 1},{v + 1},16,12")  # 1-based, as the UAV sets
        cv2.imwrite(str(seq / "frames" / f"{i + 1:06d}.png"), img)
    (seq / "boxes.txt").write_text("\n".join(lines) + "\n")
    return root


def test_bench_on_a_box_sequence(tmp_path, rng, capsys):
    data = _make_box_dataset(tmp_path / "data", rng)
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
    data = _make_box_dataset(tmp_path / "data", rng, n=20)
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
    data = _make_box_dataset(tmp_path / "data", rng, n=3)
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


def test_detect_takes_a_target_image(tmp_path, rng, monkeypatch):
    """``--target-image`` and the mission file's ``target.appearance_image`` become the colour
    model of the appearance prior after the detector."""
    from eaglemission.perception.appearance import TargetAppearance

    data = _make_box_dataset(tmp_path / "data", rng, n=2)
    frames = data / "set" / "seq" / "frames"
    crop = np.full((12, 16, 3), (40, 200, 240), np.uint8)
    cv2.imwrite(str(tmp_path / "target.png"), crop)
    seen = []
    orig = TargetAppearance.__init__

    def spy(self, **kw):
        seen.append(kw.get("image"))
        orig(self, **kw)

    monkeypatch.setattr(TargetAppearance, "__init__", spy)
    rc = main(["detect", str(frames), "--detector", "sr", "--target-image",
               str(tmp_path / "target.png"), "--out", str(tmp_path / "o1"), "--no-video"])
    assert rc == 0 and seen[-1] is not None and (seen[-1] == crop).all()
    (tmp_path / "m").mkdir()
    cv2.imwrite(str(tmp_path / "m" / "box.png"), crop[:, :8])
    (tmp_path / "m" / "mission.yaml").write_text(
        "detector: {type: sr, params: {}}\ntarget: {length_m: 0.4, width_m: 0.25, "
        "appearance_image: box.png}\n")
    rc = main(["detect", str(frames), "--config", str(tmp_path / "m" / "mission.yaml"),
               "--out", str(tmp_path / "o2"), "--no-video"])
    assert rc == 0 and seen[-1].shape == (12, 8, 3)
    lines = [json.loads(x) for x in (tmp_path / "o2" / "detections.jsonl").read_text().splitlines()]
    ranks = [d["rank"] for d in lines[0]["detections"]]
    scores = [d["score"] for d in lines[0]["detections"]]
    assert ranks == list(range(len(ranks))) and scores == sorted(scores, reverse=True)
