"""Does MuJoCo's WebAssembly module (npm ``mujoco-js``) step the TripleSumo model as the Python bindings do?

``python benchmarks/wasm_parity.py [--steps 200] [--version 0.0.7]`` (needs node and npm; installs
``mujoco-js`` into a temp folder). The paper scene's compiled spec is written as XML (``MjSpec.to_xml``),
loaded by both engines, started at its ``qpos0`` and stepped with the same seeded random controls (held for
``frame_skip`` physics steps, as an env step holds them); prints the largest ``qpos`` difference after chosen
physics steps, beside that of the Python bindings' own model against the XML round trip (``to_xml`` prints
floats that do not all read back bit for bit). A browser arena that runs the physics in the page needs the
first column within 1e-6 over 200 steps.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import mujoco
import numpy as np

from triplesumo.model.builder import build_spec
from triplesumo.rules.config import MatchConfig

NODE_SCRIPT = """
import loadMujoco from 'mujoco-js';
import fs from 'fs';
const mujoco = await loadMujoco();
mujoco.FS.mkdir('/working');
mujoco.FS.mount(mujoco.MEMFS, { root: '.' }, '/working');
mujoco.FS.writeFile('/working/scene.xml', fs.readFileSync('scene.xml', 'utf8'));
const ctrl = JSON.parse(fs.readFileSync('ctrl.json', 'utf8'));
const model = mujoco.MjModel.loadFromXML('/working/scene.xml');
const data = new mujoco.MjData(model);
mujoco.mj_forward(model, data);
const out = [Array.from(data.qpos)];
for (const u of ctrl) {
  for (let i = 0; i < u.length; i++) data.ctrl[i] = u[i];
  mujoco.mj_step(model, data);
  out.push(Array.from(data.qpos));
}
fs.writeFileSync('qpos.json', JSON.stringify({ version: mujoco.mj_versionString(), qpos: out }));
"""


def _python_qpos(model: mujoco.MjModel, ctrl: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    qpos = [data.qpos.copy()]
    for u in ctrl:
        data.ctrl[:] = u
        mujoco.mj_step(model, data)
        qpos.append(data.qpos.copy())
    return np.array(qpos)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000, help="physics steps (default 1000: 200 env steps)")
    parser.add_argument("--version", default="0.0.7", help="mujoco-js version (default 0.0.7)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if shutil.which("node") is None or shutil.which("npm") is None:
        raise SystemExit("needs node and npm on PATH")
    cfg = MatchConfig()
    spec = build_spec(cfg.agents, cfg.physics)
    model = spec.compile()
    xml = spec.to_xml()
    from_xml = mujoco.MjModel.from_xml_string(xml)
    rng = np.random.default_rng(args.seed)
    skip = cfg.physics.frame_skip
    held = rng.uniform(model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1],
                       size=(-(-args.steps // skip), model.nu))
    ctrl = held.repeat(skip, axis=0)[:args.steps]
    ours, reread = _python_qpos(model, ctrl), _python_qpos(from_xml, ctrl)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "scene.xml").write_text(xml)
        (folder / "ctrl.json").write_text(json.dumps(ctrl.tolist()))
        (folder / "parity.mjs").write_text(NODE_SCRIPT)
        (folder / "package.json").write_text('{"type": "module"}')
        subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--silent", f"mujoco-js@{args.version}"],
                       cwd=folder, check=True)
        subprocess.run(["node", "parity.mjs"], cwd=folder, check=True)
        result = json.loads((folder / "qpos.json").read_text())
    wasm = np.array(result["qpos"])
    print(f"MuJoCo {mujoco.__version__} (Python) against {result['version']} (mujoco-js {args.version}), paper scene, "
          f"integrator {mujoco.mjtIntegrator(model.opt.integrator).name}, timestep {model.opt.timestep}, "
          f"controls held {skip} steps")
    print(f"{'physics steps':>14} {'env steps':>9} {'wasm vs python, same XML':>25} {'XML vs compiled spec':>21}")
    for k in (1, 5, 10, 50, 100, 200, 500, 1000):
        if k <= args.steps:
            print(f"{k:>14} {k / skip:>9g} {np.abs(wasm[k] - reread[k]).max():>25.3g} "
                  f"{np.abs(reread[k] - ours[k]).max():>21.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
