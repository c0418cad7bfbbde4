"""A campaign's output folder as its progress: an interrupted campaign resumes from it.

``campaign.json`` names the campaign (seed, SHA-256 of the base mission file); each finished run
is ``run_NNN.result.json`` (run index, campaign seed, SHA-256 of the run's randomised config and
its result), written atomically as the run finishes. Run again with the same ``--out``, the
campaign flies only the runs without a result; a folder written by another seed or mission file,
or a run whose stored config differs from the one drawn now, is refused
(:class:`CampaignResumeError`) rather than mixed in. More ``--runs`` than before extend it (run
``i``'s world depends only on the seed and ``i``).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from eaglemission.errors import EagleMissionError

MANIFEST = "campaign.json"


class CampaignResumeError(EagleMissionError):
    """The output folder belongs to another campaign."""


def config_sha256(cfg: dict[str, Any]) -> str:
    """SHA-256 of a config mapping (JSON with sorted keys)."""
    blob = json.dumps(cfg, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def _write_atomic(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1, default=str))
    os.replace(tmp, path)


def result_path(out_dir: Path, index: int) -> Path:
    return out_dir / f"run_{index:03d}.result.json"


class RunStore:
    """Finished runs of one campaign (``seed``, base config hash ``base_sha256``) in
    ``out_dir``; :meth:`open` creates or checks the folder."""

    def __init__(self, out_dir: Path, *, seed: int, base_sha256: str) -> None:
        self.out_dir, self.seed, self.base_sha256 = out_dir, seed, base_sha256

    @classmethod
    def open(cls, out_dir: str | Path, *, seed: int, base_cfg: dict[str, Any]) -> RunStore:
        """The store of ``out_dir`` (created if new); refuses a folder of another campaign."""
        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        store = cls(d, seed=seed, base_sha256=config_sha256(base_cfg))
        mine = {"seed": seed, "config_sha256": store.base_sha256}
        path = d / MANIFEST
        if path.exists():
            try:
                theirs = json.loads(path.read_text())
            except (OSError, ValueError) as exc:
                raise CampaignResumeError(f"{path}: unreadable ({exc}): delete it or use "
                                          "another --out") from exc
            diff = [f"{k} {theirs.get(k)!r} there, {v!r} now" for k, v in mine.items()
                    if theirs.get(k) != v]
            if diff:
                raise CampaignResumeError(
                    f"{d}: holds another campaign ({'; '.join(diff)}): resume it with its "
                    "own seed and mission file, or use another --out")
        else:
            _write_atomic(path, mine)
        return store

    def finished(self, index: int, cfg: dict[str, Any]) -> dict[str, Any] | None:
        """Run ``index``'s stored result, ``None`` if it has none (or only a torn write);
        refuses a result stored for another config or seed."""
        path = result_path(self.out_dir, index)
        try:
            rec = json.loads(path.read_text())
        except FileNotFoundError:
            return None
        except ValueError:
            return None  # not one of ours (ours are written atomically): fly the run again
        want = config_sha256(cfg)
        if rec.get("seed") != self.seed or rec.get("config_sha256") != want \
                or rec.get("run") != index:
            raise CampaignResumeError(
                f"{path}: stored for run {rec.get('run')!r}, seed {rec.get('seed')!r}, config "
                f"{str(rec.get('config_sha256'))[:12]}; now run {index}, seed {self.seed}, config "
                f"{want[:12]}: use another --out (or delete the folder to start again)")
        result: dict[str, Any] = rec["result"]
        return result

    def save(self, index: int, cfg: dict[str, Any], result: dict[str, Any]) -> None:
        """Store run ``index``'s result (atomically)."""
        _write_atomic(result_path(self.out_dir, index),
                      {"run": index, "seed": self.seed, "config_sha256": config_sha256(cfg),
                       "result": result})
