"""``eaglemission detect`` on tiny generated data, and the detector specs it and ``bench``
parse."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from saliency_datasets import make_box_dataset, make_mask_dataset

from eaglemission.cli import main
from eaglemission.commands.params import UsageError, parse_detector_specs, parse_kv
from eaglemission.perception.overlay import MIN_WIDTH_PX


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


def test_detect_on_image_folder_and_video(tmp_path, rng, capsys):
    data = make_mask_dataset(tmp_path / "data", rng, seqs=("alpha",), n=3, size=(96, 72))
    frames = data / "alpha" / "frames"
    out = tmp_path / "out_imgs"
    rc = main(["detect", str(frames), "--detector", "ft", "--out", str(out),
               "--params", "regions.min_area_px=20"])
    assert rc == 0
    jpgs = sorted(out.glob("*.jpg"))
    # the 96 x 72 frame at the top-left, padded to the overlay's narrowest width, legend below
    shape = cv2.imread(str(jpgs[0])).shape
    assert len(jpgs) == 3 and shape[1] == MIN_WIDTH_PX and shape[0] > 72 and shape[2] == 3
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
    data = make_mask_dataset(tmp_path / "data", rng, seqs=("alpha",), n=1, size=(96, 72))
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


def test_detect_takes_a_target_image(tmp_path, rng, monkeypatch):
    """``--target-image`` and the mission file's ``target.appearance_image`` become the colour
    model of the appearance prior after the detector."""
    from eaglemission.perception.appearance import TargetAppearance

    data = make_box_dataset(tmp_path / "data", rng, n=2)
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

