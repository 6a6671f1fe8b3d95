"""Match pages: one self-contained HTML file that replays a recorded match in the browser.

``triplesumo view match.npz --out match.html`` (and ``play --html``, ``replay --html``,
``evaluate --record-html N``) re-simulates a match file (:func:`~triplesumo.evaluation.recording.resimulate`,
bit for bit) and writes a page that draws it with three.js:

- **the scene** is read from the compiled ``MjModel``: every geom's type (plane, sphere, capsule,
  ellipsoid, cylinder, box), size, colour (its material's texture colour where it has one) and its pose in its
  body; per frame the page gets each moving body's position and quaternion (``data.xpos``, ``data.xquat``) as
  float32, base64-encoded, and places the geoms as MuJoCo does (``geom_xpos = xpos + xmat @ geom_pos``);
- **the overlays** are the step, the outcome, and each agent's reward terms (the ``info`` the rules returned
  at each step of the re-simulation) on a timeline the scrubber moves along;
- **the cameras** are the model's own (``overview``, ``top``: position, orientation and ``fovy``), plus
  orbit/zoom/pan (three.js ``OrbitControls``) and a camera that follows an agent.

The page needs no network: three.js (MIT, vendored from npm by ``web/vendor_three.sh``, its licence in
``web/three-LICENSE``) and the page's own script (``web/viewer.js``) are inlined into it. Its URL takes
``?frame=N`` (show that frame, paused), ``&camera=overview|top|follow:AGENT``, ``&bare=1`` (the canvas
alone, filling the window: for screenshots) and ``&flat=1`` (unlit colours, for silhouette masks); the page
sets ``window.__ready`` when the frame is drawn.
"""

from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.envs.match import Match
from triplesumo.evaluation.recording import MatchFile, MatchFileError, recorded_matches, resimulate_steps
from triplesumo.rules import rewards as rules_rewards
from triplesumo.rules.outcome import outcome_name

PAGE_FORMAT = "triplesumo-view-1"
"""Format tag of the data embedded in a page (``<script type="application/json" id="match-data">``)."""
WEB = resources.files("triplesumo") / "evaluation" / "web"
GEOM_TYPES = {mujoco.mjtGeom.mjGEOM_PLANE: "plane", mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
              mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule", mujoco.mjtGeom.mjGEOM_ELLIPSOID: "ellipsoid",
              mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder", mujoco.mjtGeom.mjGEOM_BOX: "box"}
"""The geom types a page draws (the only ones TripleSumo's models hold); any other is refused by name."""


@dataclass(frozen=True)
class ViewConfig:
    """Options of ``triplesumo view FILE``."""

    out: str = "match.html"
    """The page to write (.html)."""
    verify: bool = True
    """Re-simulate the match from its seed and actions, check every state bit for bit, and show the reward
    terms the rules gave; ``--no-verify`` draws the recorded states alone (e.g. a file from another machine
    that no longer re-simulates bit for bit), without reward terms."""
    stride: int = 1
    """Keep every ``stride``-th frame (and always the last): a smaller page for a long match."""
    title: str | None = None
    """Page title (default: the match file's name)."""

    def __post_init__(self) -> None:
        check_html_path(self.out, "ViewConfig.out")
        if not isinstance(self.stride, int) or isinstance(self.stride, bool) or self.stride < 1:
            raise ValueError(f"ViewConfig.stride must be an int >= 1, got {self.stride!r}")


def check_html_path(path: str, where: str) -> None:
    """``ValueError`` naming ``where`` unless ``path`` ends in ``.html``."""
    if not str(path).endswith(".html"):
        raise ValueError(f"{where} must be a .html path, got {path!r}")


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype="<f4").tobytes()).decode("ascii")


def _geom_colour(model: mujoco.MjModel, g: int) -> list[float]:
    """A geom's RGBA as MuJoCo draws it: its material's colour times the mean colour of the material's
    texture where it has those, else the geom's own ``rgba``."""
    mat = int(model.geom_matid[g])
    if mat < 0:
        return [round(float(c), 4) for c in model.geom_rgba[g]]
    rgba = np.array(model.mat_rgba[mat], dtype=np.float64)
    tex = int(model.mat_texid[mat, mujoco.mjtTextureRole.mjTEXROLE_RGB])
    if tex >= 0:
        start, w, h, nc = int(model.tex_adr[tex]), int(model.tex_width[tex]), int(model.tex_height[tex]), \
            int(model.tex_nchannel[tex])
        pixels = model.tex_data[start:start + w * h * nc].reshape(-1, nc)[:, :3]
        rgba[:3] *= pixels.mean(axis=0) / 255.0
    return [round(float(c), 4) for c in rgba]


def _plane_texture(model: mujoco.MjModel, g: int, side: int = 20) -> dict[str, Any] | None:
    """A plane's 2D texture (its material's), sampled down to at most ``side`` x ``side`` RGB pixels (MuJoCo's
    builtin checker keeps its squares), with the material's repeat and colour; ``None`` if it has none."""
    mat = int(model.geom_matid[g])
    if mat < 0 or int(model.geom_type[g]) != int(mujoco.mjtGeom.mjGEOM_PLANE):
        return None
    tex = int(model.mat_texid[mat, mujoco.mjtTextureRole.mjTEXROLE_RGB])
    if tex < 0 or int(model.tex_type[tex]) != int(mujoco.mjtTexture.mjTEXTURE_2D):
        return None
    w, h, nc = int(model.tex_width[tex]), int(model.tex_height[tex]), int(model.tex_nchannel[tex])
    pixels = model.tex_data[int(model.tex_adr[tex]):int(model.tex_adr[tex]) + w * h * nc].reshape(h, w, nc)[..., :3]
    step_y, step_x = max(1, h // side), max(1, w // side)
    small = np.ascontiguousarray(pixels[step_y // 2::step_y, step_x // 2::step_x], dtype=np.uint8)
    return {"width": int(small.shape[1]), "height": int(small.shape[0]),
            "rgb": base64.b64encode(small.tobytes()).decode("ascii"),
            "repeat": [float(r) for r in model.mat_texrepeat[mat]],
            "rgba": [round(float(c), 4) for c in model.mat_rgba[mat]]}


def scene_description(model: mujoco.MjModel, agents: tuple[str, ...]) -> dict[str, Any]:
    """The static scene: bodies that move, every visible geom with its body, local pose, type, size and colour,
    and the model's cameras. ``ValueError`` names a geom of a type a page cannot draw."""
    moving = [b for b in range(1, model.nbody) if np.any(model.geom_bodyid == b)]
    slot = {b: k for k, b in enumerate(moving)}
    geoms = []
    for g in range(model.ngeom):
        if model.geom_rgba[g, 3] == 0 and int(model.geom_matid[g]) < 0:
            continue  # invisible
        kind = GEOM_TYPES.get(mujoco.mjtGeom(int(model.geom_type[g])))
        if kind is None:
            raise ValueError(f"geom {model.geom(g).name!r} has type {mujoco.mjtGeom(int(model.geom_type[g])).name}, "
                             "which a match page cannot draw")
        body = int(model.geom_bodyid[g])
        owner = model.body(body).name.split("/")[0] if body else None
        geoms.append({"name": model.geom(g).name, "type": kind, "body": slot.get(body, -1),
                      "agent": agents.index(owner) if owner in agents else -1,
                      "size": [round(float(s), 6) for s in model.geom_size[g]],
                      "pos": [float(p) for p in model.geom_pos[g]], "quat": [float(q) for q in model.geom_quat[g]],
                      "rgba": _geom_colour(model, g), "texture": _plane_texture(model, g)})
    cameras = {}
    for c in range(model.ncam):
        cameras[model.camera(c).name] = {"pos": [float(p) for p in model.cam_pos[c]],
                                         "mat": [float(m) for m in model.cam_mat0[c]],
                                         "fovy": float(model.cam_fovy[c])}
    lights = [{"pos": [float(p) for p in model.light_pos[i]], "dir": [float(d) for d in model.light_dir[i]],
               "diffuse": [float(d) for d in model.light_diffuse[i]],
               "directional": int(model.light_type[i]) == int(mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)}
              for i in range(model.nlight)]
    return {"bodies": [model.body(b).name for b in moving], "body_ids": moving, "geoms": geoms,
            "cameras": cameras, "lights": lights,
            "headlight": {"ambient": [float(a) for a in model.vis.headlight.ambient],
                          "diffuse": [float(d) for d in model.vis.headlight.diffuse]},
            "znear": float(model.vis.map.znear * model.stat.extent),
            "zfar": float(model.vis.map.zfar * model.stat.extent)}


def page_data(record: MatchFile, verify: bool = True, stride: int = 1, title: str = "match") -> dict[str, Any]:
    """Everything a page shows, as JSON-able data: the scene, per kept frame each moving body's float32
    position and quaternion (base64, ``(frames, bodies, 7)``), per step each agent's reward terms
    (``(steps, agents, terms)``), the outcome. ``MatchFileError`` if ``verify`` and the re-simulation
    differs from the recorded states."""
    match = Match(record.config)
    agents = tuple(match.agents)
    scene = scene_description(match.model, agents)
    moving = np.array(scene.pop("body_ids"), dtype=np.int64)
    kept = sorted(set(range(0, record.steps + 1, stride)) | {record.steps})
    wanted = set(kept)
    poses = np.zeros((len(kept), len(moving), 7), dtype=np.float32)
    terms = rules_rewards.TERMS
    rewards = np.zeros((record.steps, len(agents), len(terms)), dtype=np.float32)
    out_of_ring = np.zeros((record.steps, len(agents)), dtype=bool)
    outcome_codes: list[int] = []
    row = 0
    frames = resimulate_steps(record) if verify else ((m, None) for m in recorded_matches(record))
    for t, (sim, result) in enumerate(frames):
        if result is not None:
            for i, info in enumerate(result.infos):
                rewards[t - 1, i] = [info[k] for k in terms]
                out_of_ring[t - 1, i] = bool(info["out_of_ring"])
            outcome_codes = [int(info["outcome"]) for info in result.infos]
        if t in wanted:
            poses[row, :, :3] = sim.data.xpos[moving]
            poses[row, :, 3:] = sim.data.xquat[moving]
            row += 1
    outcomes = {a: record.outcomes.get(a) for a in agents}
    if not any(outcomes.values()) and outcome_codes:  # a file written without outcomes: the rules' last word
        outcomes = {a: outcome_name(c) for a, c in zip(agents, outcome_codes, strict=True)}
    physics = record.config.physics
    return {
        "format": PAGE_FORMAT, "title": title, "seed": record.seed, "steps": record.steps,
        "fps": 1.0 / (physics.timestep * physics.frame_skip), "frames": kept,
        "agents": [{"name": a.name, "team": a.team, "rgba": list(a.rgba), "policy": record.policies.get(a.name),
                    "outcome": outcomes.get(a.name)} for a in record.config.agents],
        "scenario_rules": record.config.rules, "verified": verify,
        **scene,
        "poses": _b64(poses),
        "terms": list(terms) if verify else [],
        "rewards": _b64(rewards) if verify else "",
        "out_of_ring": [[int(s) for s in np.flatnonzero(out_of_ring[:, i]) + 1] for i in range(len(agents))],
    }


def build_page(record: MatchFile, verify: bool = True, stride: int = 1, title: str = "match") -> str:
    """The page's HTML text (see the module's docstring)."""
    data = page_data(record, verify, stride, title)
    payload = json.dumps(data, separators=(",", ":")).replace("<", "\\u003c")  # no "</script" or "<!--" inside
    three = (WEB / "three.min.js").read_text(encoding="utf-8")
    script = (WEB / "viewer.js").read_text(encoding="utf-8")
    style = (WEB / "viewer.css").read_text(encoding="utf-8")
    for name, text in (("three.min.js", three), ("viewer.js", script)):
        if "</script" in text.lower():  # would end the inline script early
            raise RuntimeError(f"web/{name} holds '</script': it cannot be inlined")
    return (f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            f"<title>{html.escape(title)} - TripleSumo</title>\n<style>\n{style}</style>\n</head>\n<body>\n"
            f"<script type=\"application/json\" id=\"match-data\">{payload}</script>\n"
            "<!-- three.js r187 (https://threejs.org), MIT License, Copyright 2010-2026 three.js authors -->\n"
            f"<script>\n{three}\n</script>\n<script>\n{script}</script>\n</body>\n</html>\n")


def read_page_data(text: str) -> dict[str, Any]:
    """The data embedded in a page's HTML text (the inverse of :func:`build_page`'s embedding), with
    ``poses`` decoded to a ``(frames, bodies, 7)`` float32 array and ``rewards`` to ``(steps, agents, terms)``."""
    start_tag = '<script type="application/json" id="match-data">'
    start = text.index(start_tag) + len(start_tag)
    data = json.loads(text[start:text.index("</script>", start)])
    data["poses"] = np.frombuffer(base64.b64decode(data["poses"]), dtype="<f4").reshape(
        len(data["frames"]), len(data["bodies"]), 7)
    if data["rewards"]:
        data["rewards"] = np.frombuffer(base64.b64decode(data["rewards"]), dtype="<f4").reshape(
            data["steps"], len(data["agents"]), len(data["terms"]))
    return data


def write_page(record: MatchFile, out: Path, verify: bool = True, stride: int = 1, title: str = "match",
               source: Path | None = None) -> Path:
    """Build the page and write it to ``out`` atomically; nothing is written if building fails. A re-simulation
    that parts from the file raises ``MatchFileError`` naming ``source``."""
    out = Path(out)
    check_html_path(str(out), "the page")
    try:
        text = build_page(record, verify, stride, title)
    except MatchFileError as exc:
        if source is None:
            raise
        raise MatchFileError(f"{source}: {exc}") from None
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        atomic_write_bytes(out, text.encode("utf-8"))
        out.chmod(0o644)  # a page to share or serve (the temp file it was renamed from was private)
    except OSError as exc:
        raise OSError(exc.errno, f"{out}: the page was not written ({exc.strerror or exc})") from exc
    return out


def run_view(path: Path, cfg: ViewConfig) -> Path:
    """``triplesumo view``: load a match file, write its page, print where."""
    path = Path(path)
    record = MatchFile.load(path)
    out = write_page(record, Path(cfg.out), cfg.verify, cfg.stride, cfg.title or path.name, source=path)
    size = out.stat().st_size
    print(f"page: {out} ({size / 1e6:.2f} MB, {record.steps} steps; open it in a browser, no network needed)")
    return out
