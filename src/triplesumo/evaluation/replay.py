"""``triplesumo replay FILE``: check a match file re-simulates bit for bit, and re-render it as a video or a page."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from triplesumo.evaluation.recording import MatchFile, MatchFileError, render_frames, verify
from triplesumo.evaluation.viewer import check_html_path, write_page


@dataclass(frozen=True)
class ReplayConfig:
    """Options of ``triplesumo replay FILE``."""

    video: str | None = None
    """Render the recorded states as mp4 to this path."""
    html: str | None = None
    """Write a self-contained HTML page that replays the match in a browser to this path (as ``triplesumo view``)."""
    verify: bool = True
    """Re-simulate the match from its seed and actions, check every state is bit-identical, and render
    the re-simulation (exactly the frames ``play --video`` rendered); ``--no-verify`` renders the
    recorded states alone."""
    width: int = 480
    """Video width in pixels."""
    height: int = 480
    """Video height in pixels."""

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise ValueError("ReplayConfig.width and height must be >= 16")
        if self.html is not None:
            check_html_path(self.html, "ReplayConfig.html")


def run_replay(path: Path, cfg: ReplayConfig) -> MatchFile:
    """Load, optionally verify, and optionally render a match file; prints what it did."""
    from triplesumo.evaluation.video import check_writable

    if cfg.video is not None:
        check_writable(Path(cfg.video))
    record = MatchFile.load(Path(path))
    try:
        _replay(path, record, cfg)
    except MatchFileError as exc:  # the re-simulation parted from the file: say which file
        raise MatchFileError(f"{path}: {exc}") from None
    return record


def _replay(path: Path, record: MatchFile, cfg: ReplayConfig) -> None:
    """:func:`run_replay` after the file is loaded."""
    from triplesumo.evaluation.video import write_mp4

    who = ", ".join(f"{a}={p}" for a, p in record.policies.items()) or "unnamed policies"
    ends = ", ".join(f"{a}: {o}" for a, o in record.outcomes.items())
    print(f"{path}: seed {record.seed}, {record.steps} steps, {who}; {ends}")
    if cfg.video is not None:
        fps = round(1.0 / (record.config.physics.timestep * record.config.physics.frame_skip))
        n = write_mp4(render_frames(record, cfg.width, cfg.height, exact=cfg.verify), Path(cfg.video), fps=fps)
        print(f"video: {cfg.video} ({n} frames)")
    elif cfg.verify and cfg.html is None:
        verify(record)
    if cfg.html is not None:  # (re-simulated and checked again there when cfg.verify)
        page = write_page(record, Path(cfg.html), verify=cfg.verify, title=Path(path).name)
        print(f"page: {page} (open it in a browser; no network needed)")
    if cfg.verify:
        print(f"verified: re-simulating the recorded actions gives all {record.steps + 1} states bit for bit")
