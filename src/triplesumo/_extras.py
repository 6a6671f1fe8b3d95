"""Which extra installs which optional library: what a command says when one is missing.

``pip install triplesumo`` installs the environments only (mujoco, numpy, gymnasium, pettingzoo, safetensors);
the commands import the rest when they run. A command that meets a missing library from this table fails with
the extra to install (``triplesumo train needs PyTorch: pip install "triplesumo[train]"``), not a traceback.
Kept in step with ``[project.optional-dependencies]`` in pyproject.toml by the tests.
"""

from __future__ import annotations

import importlib.util

EXTRAS: dict[str, tuple[str, ...]] = {
    "train": ("torch", "tensorboard", "tqdm", "matplotlib", "openskill"),
    "eval": ("matplotlib", "pandas", "scipy", "rliable", "openskill", "tqdm"),
    "video": ("imageio", "imageio_ffmpeg"),
    "gpu": ("mujoco_warp", "warp"),
    "ray": ("ray",),
    "sb3": ("stable_baselines3",),
    "torchrl": ("torchrl", "tensordict"),
}
"""Extra -> the modules it makes importable (top-level names). ``[all]`` is train, eval and video."""
ALL = ("train", "eval", "video")
"""The extras ``[all]`` installs: everything the commands need on one machine (not gpu, ray, sb3 or torchrl)."""
COMMAND_EXTRAS: dict[str, tuple[str, ...]] = {
    "demo": ALL,
    "reproduce": ALL,
    "train": ("train",),
    "average": ("train",),
    "plot": ("train",),  # (a run folder's plots: train.run_folder)
    "sweep": ("train",),  # (and Ray, which it names itself)
    "evaluate": ("eval",),
    "tournament": ("eval",),
    "compare": ("eval",),
}
"""Command -> the extras it needs whatever its options (``play`` and ``replay`` need none; ``--video`` needs
``[video]``)."""
NAMES = {"torch": "PyTorch", "tensorboard": "TensorBoard", "scipy": "SciPy", "imageio": "imageio (ffmpeg)",
         "imageio_ffmpeg": "imageio-ffmpeg", "ray": "Ray", "mujoco_warp": "MuJoCo Warp", "warp": "NVIDIA Warp",
         "stable_baselines3": "Stable-Baselines3", "torchrl": "TorchRL", "tensordict": "TensorDict"}
"""How a message names a module (others by their module name)."""


def extra_for(command: str, module: str) -> str | None:
    """The extra to install for ``command`` that met ``module`` missing (``"train"``, ``"all"``), or
    ``None`` for a module no extra installs. The command's own extras where one of them holds the module (so
    ``demo`` asks for ``[all]`` once, not for one extra after another), else the first extra that does."""
    top = module.split(".")[0]
    holders = [extra for extra, modules in EXTRAS.items() if top in modules]
    if not holders:
        return None
    own = COMMAND_EXTRAS.get(command, ())
    if any(top in EXTRAS[extra] for extra in own):
        return "all" if own == ALL else ",".join(own)
    return holders[0]


def require(command: str, also: tuple[str, ...] = ()) -> None:
    """``ModuleNotFoundError`` for the first module of ``command``'s extras (:data:`COMMAND_EXTRAS`) and of the
    extras ``also`` (those its options ask for, e.g. ``video``) that is not installed: a command fails before it
    starts, not at its end (``train`` writes plots after its last epoch, ``play --video`` encodes after the match)."""
    for extra in (*COMMAND_EXTRAS.get(command, ()), *also):
        for module in EXTRAS[extra]:
            if importlib.util.find_spec(module) is None:
                raise ModuleNotFoundError(f"No module named {module!r}", name=module)


def missing_message(command: str, module: str) -> str | None:
    """``triplesumo COMMAND needs NAME: pip install "triplesumo[EXTRA]"`` for a missing ``module``, or ``None``
    where no extra installs it (a real bug: let its traceback show)."""
    extra = extra_for(command, module)
    if extra is None:
        return None
    top = module.split(".")[0]
    return f'triplesumo {command} needs {NAMES.get(top, top)}: pip install "triplesumo[{extra}]"'
