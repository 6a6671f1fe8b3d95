"""torch's thread count in the process an adapter trains in."""

from __future__ import annotations

DEFAULT_THREADS = 1
"""The adapters' default: SB3's PPO and SAC ran several times slower on a 2-core box with torch's default (one
intra-op thread per core, which stall whenever another process holds a core) than with one thread: 7 to 13 times
in one measurement, PPO 2 to 3 and SAC 11 to 39 times in another under a heavier load (docs/libraries.md)."""


def set_torch_threads(threads: int | None, where: str) -> None:
    """``torch.set_num_threads(threads)``; ``None`` leaves torch's setting; ``where`` names the argument."""
    if threads is None:
        return
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"{where} must be an int >= 1 (torch.set_num_threads) or None, got {threads!r}")
    import torch

    torch.set_num_threads(threads)
