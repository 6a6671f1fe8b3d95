"""Replayable match files: play/evaluate --record, replay, exactness, bad files."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from triplesumo.agents.builtin import RandomPolicy
from triplesumo.cli import main
from triplesumo.evaluation.evaluate import play_test_epochs
from triplesumo.evaluation.recording import FORMAT, MatchFile, MatchFileError, render_frames, resimulate, verify
from triplesumo.evaluation.runner import play_match
from triplesumo.evaluation.video import count_frames
from triplesumo.model import BODIES_AGENTS
from triplesumo.rules.config import MatchConfig

MIXED = MatchConfig(agents=BODIES_AGENTS, max_steps=40)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, MatchFile]:
    """A mixed-body match between random policies, recorded."""
    path = tmp_path_factory.mktemp("match") / "match.npz"
    policies = {"ant": RandomPolicy(1, 8), "bug": RandomPolicy(2, 12), "spider": RandomPolicy(3, 16)}
    played = play_match(policies, seed=7, config=MIXED, record=path,
                        policy_names=dict.fromkeys(policies, "random"))
    record = MatchFile.load(path)
    assert record.steps == played.steps
    return path, record


def test_a_match_file_holds_seed_config_actions_and_states(recorded: tuple[Path, MatchFile]) -> None:
    _, record = recorded
    assert record.seed == 7
    assert record.config == MIXED
    assert record.actions.shape == (40, 3, 16)
    assert (record.actions[:, 0, 8:] == 0).all() and (record.actions[:, 1, 12:] == 0).all()
    assert np.abs(record.actions[:, 2]).max() <= 1.0 and np.abs(record.actions[:, 2]).max() > 0.9
    assert record.states.shape[0] == 41
    assert record.policies == {"ant": "random", "bug": "random", "spider": "random"}
    assert set(record.outcomes.values()) <= {"win", "loss", "draw"}


def test_replaying_gives_every_recorded_state_bit_for_bit(recorded: tuple[Path, MatchFile]) -> None:
    _, record = recorded
    states = [m.data.qpos.copy() for m in resimulate(record)]
    assert len(states) == record.steps + 1
    assert verify(record) == 40
    assert not np.array_equal(states[0], states[-1])  # the match moved: the check compares something


def test_a_changed_action_or_state_is_caught_at_its_step(recorded: tuple[Path, MatchFile]) -> None:
    _, record = recorded
    actions = record.actions.copy()
    actions[12, 1, 3] += 1e-9
    with pytest.raises(MatchFileError, match="differs from the recording at step 13"):
        verify(dataclasses.replace(record, actions=actions))
    states = record.states.copy()
    states[25, 0] = np.nextafter(states[25, 0], np.inf)
    with pytest.raises(MatchFileError, match="differs from the recording at step 25"):
        verify(dataclasses.replace(record, states=states))


def test_render_from_states_alone_matches_the_resimulation_at_the_start(recorded: tuple[Path, MatchFile]) -> None:
    _, record = recorded
    short = dataclasses.replace(record, actions=record.actions[:2], states=record.states[:3])
    exact = list(render_frames(short, 64, 64))
    loose = list(render_frames(short, 64, 64, exact=False))
    assert len(exact) == len(loose) == 3
    np.testing.assert_array_equal(exact[0], loose[0])  # after a reset both are mj_forward of the same state
    assert exact[2].std() > 0


def _write(path: Path, **arrays: np.ndarray) -> Path:
    with path.open("wb") as f:
        np.savez(f, **arrays)  # type: ignore[arg-type]
    return path


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def test_bad_files_get_clear_errors(recorded: tuple[Path, MatchFile], tmp_path: Path) -> None:
    path, _ = recorded
    good = _arrays(path)
    with pytest.raises(FileNotFoundError, match="no match file"):
        MatchFile.load(tmp_path / "none.npz")
    (tmp_path / "text.npz").write_text("not a zip")
    with pytest.raises(MatchFileError, match="not a readable .npz match file"):
        MatchFile.load(tmp_path / "text.npz")
    (tmp_path / "cut.npz").write_bytes(path.read_bytes()[:2000])
    with pytest.raises(MatchFileError, match="not a readable .npz match file"):
        MatchFile.load(tmp_path / "cut.npz")
    with pytest.raises(MatchFileError, match=r"not a TripleSumo match file \(missing \['states'\]\)"):
        MatchFile.load(_write(tmp_path / "a.npz", **{k: v for k, v in good.items() if k != "states"}))
    with pytest.raises(MatchFileError, match="not a readable"):  # pickled objects are never loaded
        MatchFile.load(_write(tmp_path / "p.npz", **{**good, "meta": np.array([{"seed": 1}], dtype=object)}))
    with pytest.raises(MatchFileError, match=f"this version reads '{FORMAT}'"):
        MatchFile.load(_write(tmp_path / "f.npz", **{**good, "format": np.array("other-9")}))
    config = json.loads(str(good["config"]))
    with pytest.raises(MatchFileError, match=r"config has fields \['gravity'\] unknown to MatchConfig"):
        MatchFile.load(_write(tmp_path / "u.npz", **{**good, "config": np.array(json.dumps({**config, "gravity": 1}))}))
    config["agents"][1]["body"] = "snake"
    with pytest.raises(MatchFileError, match="recorded config is not valid here: AgentSpec.body of 'bug'"):
        MatchFile.load(_write(tmp_path / "b.npz", **{**good, "config": np.array(json.dumps(config))}))
    paper = json.dumps(dataclasses.asdict(MatchConfig(max_steps=40)))
    with pytest.raises(MatchFileError, match=r"actions must be float64 of shape \(steps, 3, 8\) for this roster"):
        MatchFile.load(_write(tmp_path / "m.npz", **{**good, "config": np.array(paper)}))
    with pytest.raises(MatchFileError, match=r"states must be float64 of shape \(41, "):
        MatchFile.load(_write(tmp_path / "s.npz", **{**good, "states": good["states"][:-1]}))


def test_play_record_then_replay_video_from_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    file, video = tmp_path / "m.npz", tmp_path / "replay.mp4"
    assert main(["play", "--seed", "2", "--max-steps", "12", "--record", str(file)]) == 0
    assert main(["replay", str(file), "--video", str(video), "--width", "64", "--height", "64"]) == 0
    out = capsys.readouterr().out
    assert "verified: re-simulating the recorded actions gives all 13 states bit for bit" in out
    assert count_frames(video) == 13
    (tmp_path / "bad.npz").write_text("x")
    assert main(["replay", str(tmp_path / "bad.npz")]) == 2
    assert "not a readable .npz match file" in capsys.readouterr().err
    assert main(["play", "--record", str(tmp_path / "m.json")]) == 2


def test_evaluation_records_its_first_k_matches_and_they_replay(tmp_path: Path) -> None:
    """Matches stepped together in a MatchBatch replay exactly in a single Match."""
    others = {"ant": RandomPolicy(4, 8), "spider": RandomPolicy(5, 16)}
    rows = play_test_epochs(RandomPolicy(6, 12), others, "bug", 3, 100, MatchConfig(agents=BODIES_AGENTS, max_steps=25),
                            n_envs=2, record=2, record_dir=tmp_path, policy_names={"bug": "random"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["epoch_00001.npz", "epoch_00002.npz"]
    for epoch in (1, 2):
        record = MatchFile.load(tmp_path / f"epoch_{epoch:05d}.npz")
        assert record.seed == 100 + epoch - 1
        assert record.steps == rows[epoch - 1]["steps"]
        assert verify(record) == record.steps


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_evaluate_record_from_the_command_line(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", "--policy", "random", "--policies", "ant=random", "spider=random", "--baselines",
                 "passive", "--epochs", "3", "--steps-per-epoch", "10", "--n-envs", "2", "--out", str(out),
                 "--no-progress", "--record", "1"]) == 0
    for label in ("trained", "passive"):
        files = sorted((out / label / "matches").iterdir())
        assert [f.name for f in files] == ["epoch_00001.npz"]
        assert MatchFile.load(files[0]).policies["bug"] == ("random" if label == "trained" else "passive")
    assert main(["evaluate", "--record", "-1", "--out", str(out)]) == 2


def test_a_failed_write_keeps_the_earlier_match_file_and_names_it(recorded: tuple[Path, MatchFile], tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 39, item 16 D: ``play --record FILE`` onto an existing recording with a full disk overwrote it in
    place (a corrupt zip) and named no file. The write is atomic now: a disk that fills while the temp file is
    written leaves the earlier file whole and the error names the path."""
    import errno
    import os

    _, match = recorded
    path = tmp_path / "match.npz"
    match.save(path)
    before = path.read_bytes()
    real_fdopen = os.fdopen

    class FullDisk:
        def __init__(self, fh: object) -> None:
            self.fh = fh

        def __enter__(self) -> FullDisk:
            return self

        def __exit__(self, *exc: object) -> None:
            self.fh.close()  # type: ignore[attr-defined]

        def write(self, data: bytes) -> int:
            self.fh.write(data[: len(data) // 2])  # type: ignore[attr-defined]
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fdopen", lambda fd, mode="r": FullDisk(real_fdopen(fd, mode)))
    with pytest.raises(OSError, match=rf"{path}: the match file was not written \(No space left on device\)"):
        match.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before and MatchFile.load(path).steps == match.steps
    assert [p.name for p in tmp_path.iterdir()] == ["match.npz"]  # no temp file left behind


@pytest.mark.parametrize(("damage", "reason"), [
    (lambda old: [1, 2], "expected a JSON object, got list"),
    (lambda old: {k: v for k, v in old.items() if k != "seed"}, "seed must be an integer, got None"),
    (lambda old: {**old, "seed": None}, "seed must be an integer, got None"),
    (lambda old: {**old, "outcomes": 5}, "outcomes must be a JSON object, got 5"),
], ids=["list", "no-seed", "null-seed", "outcomes-5"])
def test_damaged_metadata_is_a_clear_error(recorded: tuple[Path, MatchFile], tmp_path: Path, damage: Any,
                                           reason: str) -> None:
    """Issue 39, item 16 T: a list as meta, a missing or null seed, ``outcomes: 5`` were raw tracebacks."""
    path, _ = recorded
    good = _arrays(path)
    meta = damage(json.loads(str(good["meta"])))
    bad = _write(tmp_path / "meta.npz", **{**good, "meta": np.array(json.dumps(meta))})
    with pytest.raises(MatchFileError, match=f"{bad}: corrupt metadata: {reason}"):
        MatchFile.load(bad)


def test_lying_headers_zip_bombs_and_broken_deflate_are_refused_before_reading(
        recorded: tuple[Path, MatchFile], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 39, item 16 T: a header claiming 31 PiB raised MemoryError, a 2 MB zip bomb allocated 2.3 GB before
    it was refused, and a broken deflate stream was a zlib traceback. Sizes are read from the headers first."""
    import io
    import zipfile

    from triplesumo.evaluation import recording

    path, _ = recorded
    good = _arrays(path)
    # a lying npy header: (2**50,) float64 declared, 8 bytes of data
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (2**50,)})
    lying = tmp_path / "lying.npz"
    with zipfile.ZipFile(lying, "w") as zf:
        for key, value in good.items():
            if key == "states":
                zf.writestr("states.npy", buf.getvalue() + b"\0" * 8)
            else:
                one = io.BytesIO()
                np.save(one, value)
                zf.writestr(f"{key}.npy", one.getvalue())
    with pytest.raises(MatchFileError, match=r"states.npy's header declares 9,007,199,254,740,992 bytes"):
        MatchFile.load(lying)
    # a zip bomb: a member that unpacks past the limit (here lowered to 1 MiB for a 2 MiB array of zeros)
    monkeypatch.setattr(recording, "MAX_MEMBER_BYTES", 1 << 20)
    bomb = tmp_path / "bomb.npz"
    with bomb.open("wb") as f:
        np.savez_compressed(f, **{**good, "states": np.zeros((1 << 18,))})
    assert bomb.stat().st_size < 100_000
    with pytest.raises(MatchFileError, match=r"states.npy would unpack to 2,097,\d+ bytes"):
        MatchFile.load(bomb)
    monkeypatch.undo()
    # a broken deflate stream inside a compressed member
    data = bytearray(path.read_bytes())
    at = data.index(b"states.npy") + 200
    data[at:at + 64] = bytes(64)
    (tmp_path / "deflate.npz").write_bytes(bytes(data))
    with pytest.raises(MatchFileError, match="not a readable .npz match file"):
        MatchFile.load(tmp_path / "deflate.npz")


def test_a_match_file_recorded_before_env_v2_replays_on_its_own_ring(tmp_path: Path) -> None:
    """A v1 match file's config has no layout or rim shape: it reads back as v1's circle and cylinders (not v2's
    defaults), so its recorded states still replay bit for bit."""
    from triplesumo.model import V1_PHYSICS

    config = MatchConfig(physics=V1_PHYSICS, max_steps=12)
    played = play_match({}, seed=4, config=config, record=tmp_path / "v1.npz")
    assert played.steps == 12
    good = _arrays(tmp_path / "v1.npz")
    old = json.loads(str(good["config"]))
    for key in ("layout", "start_edge", "rim_shape"):
        del old["physics"][key]
    path = _write(tmp_path / "old.npz", **{**good, "config": np.array(json.dumps(old))})
    loaded = MatchFile.load(path)
    assert loaded.config.physics == V1_PHYSICS
    verify(loaded)


def test_a_match_file_with_a_bad_seed_names_the_file(recorded: tuple[Path, MatchFile], tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    """Seed -5 gave numpy's "expected non-negative integer", and seed 2**70 (a seed, but not the recorded one)
    "replay differs from the recording", neither naming the file."""
    path, _ = recorded
    good = _arrays(path)
    meta = json.loads(str(good["meta"]))
    negative = _write(tmp_path / "negative.npz", **{**good, "meta": np.array(json.dumps({**meta, "seed": -5}))})
    with pytest.raises(MatchFileError, match=rf"{negative}: corrupt metadata: seed must be a non-negative integer "
                                             r"\(0, 1, 2, \.\.\.\), got -5"):
        MatchFile.load(negative)
    huge = _write(tmp_path / "huge.npz", **{**good, "meta": np.array(json.dumps({**meta, "seed": 2**70}))})
    assert main(["replay", str(huge)]) == 2
    assert f"triplesumo replay: error: {huge}: replay differs from the recording at step 0" in capsys.readouterr().err


def test_a_negative_play_seed_names_the_seed_not_a_policy(capsys: pytest.CaptureFixture) -> None:
    """``play --seed -1`` said "policy 'random' for 'ant' does not fit this roster: expected non-negative
    integer"."""
    assert main(["play", "--seed", "-1", "--max-steps", "3"]) == 2
    err = capsys.readouterr().err
    assert "PlayConfig.seed must be a non-negative integer (0, 1, 2, ...), got -1" in err and "policy" not in err
