#!/usr/bin/env bash
# The GPU check of issue 53 (time to skill on MuJoCo Warp) and the Warp env benchmark, in one device call.
#
# On the GPU machine, from the repository root, with $OUT set by the device tool (results come back from it):
#     bash benchmarks/gpu_check.sh stage   # only copy the carried wheels (.whl/N) to /tmp/triplesumo-wheels
#     bash benchmarks/gpu_check.sh         # stage the last ones, install, then measure (about 8 minutes)
#     bash benchmarks/gpu_check.sh reproduce   # stage, install, then the whole reproduction on Warp (issue 51)
# The wheels come from benchmarks/gpu_wheels.sh, run beforehand on a machine with PyPI (it says how many calls).
#
# What it writes under $OUT (at most 8 files come back):
#     log.txt              everything printed
#     machine.txt          nvidia-smi, python, package versions
#     skill_gpu.json/.txt  triplesumo bench skill-gpu (seconds and env steps to +0.2 and +0.4, the curve)
#     skill_gpu.png        test MWR against env steps and against training seconds
#     evals.csv            every seed's evaluations (test MWR, env steps, both clocks), also when bench skill-gpu was
#                          stopped before writing its record
#     env_warp.json/.txt   triplesumo bench env --backend warp (env and raw mujoco_warp steps/s per size)
# or, with reproduce: reproduce.txt (what it printed), reproduce.json (each stage's wall time, the machine, the GPU, the
#     device's start-up and rate; kept when the time limit stops it mid-stage), REPRODUCTION.md, contest.json,
#     per_seed.csv (the test), screens-ant.json and screens-spider.json (stage 1's screens).
#
# Knobs (environment): DEVICE (cuda; cpu runs the same steps on Warp's CPU device, a check of this script),
# QUICK=1 (bench skill-gpu --quick, tiny sizes everywhere), SEEDS ("0": training seeds, one after another; each waits
# for its evaluations, about 2 minutes a seed on the H200), SKILL_SECONDS (150: training budget of each seed),
# TOTAL_SECONDS (480: the env benchmark gets what is left), N_ENVS (4096), ENV_SIZES (1024,4096,16384),
# PYTHON (python3), SKIP_INSTALL=1 (packages already importable). Give the call about 560 s.
# reproduce's knobs: REPRO_SECONDS (540: its time limit), REPRO_SEEDS ("0 1 2": the SAC Bugs' seeds), REPRO_PAIR
# (empty: stage 1 from scratch; "ANT SPIDER": that pair, the protocol from the contest on, e.g. pair 3's committed
# docs/runs/scratch-v2/seed-3/ant/screens/policy-4000 docs/runs/scratch-v2/seed-3/spider/screens/policy-8000),
# REPRO_ENV_STEPS (each Bug's env-step budget; empty: the protocol's); QUICK=1 runs --tiny. The protocol's wall time
# on a GPU has never been measured: a run the limit stops says how far it got.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu_check_out}
STAGE=/tmp/triplesumo-wheels
PYTHON=${PYTHON:-python3}
DEVICE=${DEVICE:-cuda}
SEEDS=${SEEDS:-0}
SKILL_SECONDS=${SKILL_SECONDS:-150}
TOTAL_SECONDS=${TOTAL_SECONDS:-480}
N_ENVS=${N_ENVS:-4096}
ENV_SIZES=${ENV_SIZES:-1024,4096,16384}
mkdir -p "$OUT" "$STAGE"
exec > >(tee -a "$OUT/log.txt") 2>&1
t_start=$(date +%s)
elapsed() { echo $(( $(date +%s) - t_start )); }

# 1. wheels: this call's carried folder(s) join those staged by earlier calls
for d in .whl/*/; do [ -d "$d" ] && cp -f "$d"* "$STAGE"/ 2>/dev/null; done
echo "staged: $(ls "$STAGE" | wc -l) files, $(du -sh "$STAGE" | cut -f1)"
[ "${1:-run}" = "stage" ] && exit 0

if [ "${SKIP_INSTALL:-0}" != "1" ]; then
    for first in "$STAGE"/*.whl.part-00; do  # reassemble the wheels cut in parts
        [ -e "$first" ] || continue
        whl=${first%.part-00}
        cat "$whl".part-* > "$whl"
    done
    (cd "$STAGE" && sha256sum -c --quiet SHA256SUMS) || { echo "wheels missing or damaged (sha256): stage every .whl/N first"; exit 3; }
    "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
        "$STAGE"/*.whl || { echo "pip install of the wheels failed"; exit 3; }
    export PYTHONPATH=/tmp/site:${PWD}/src
else
    export PYTHONPATH=${PWD}/src${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONUNBUFFERED=1
# nothing here renders; an image that sets MUJOCO_GL=egl without libEGL makes `import mujoco` fail (seen on the H200)
export MUJOCO_GL=disable
TS=("$PYTHON" -m triplesumo.cli)
{
    nvidia-smi -L 2>/dev/null || echo "no nvidia-smi"
    echo "git $(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
    "$PYTHON" - <<'EOF'
import importlib.metadata as md, platform
print("python", platform.python_version())
for p in ("torch", "numpy", "mujoco", "mujoco-warp", "warp-lang", "gymnasium", "pettingzoo", "openskill"):
    try:
        print(p, md.version(p))
    except md.PackageNotFoundError:
        print(p, "not installed")
import torch, warp
print("torch sees cuda:", torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else "")
EOF
} > "$OUT/machine.txt" 2>&1
cat "$OUT/machine.txt"
echo "[$(elapsed) s] installed"

# 2'. or the whole reproduction on Warp: stage 1's sides and the SAC Bugs on the device, every check and the test on
#     the host's CPU (docs/reproduce.md, "On a GPU")
if [ "${1:-run}" = "reproduce" ]; then
    if [ "${QUICK:-0}" = "1" ]; then
        REPRO_ARGS=(--tiny --no-sides-at-once)
    else
        REPRO_ARGS=(--workers 3 --warp-eval-workers "$(( $(nproc) > 10 ? 4 : 1 ))")
    fi
    # shellcheck disable=SC2206
    [ -n "${REPRO_PAIR:-}" ] && REPRO_ARGS+=(--pair $REPRO_PAIR)
    [ -n "${REPRO_ENV_STEPS:-}" ] && REPRO_ARGS+=(--bug-env-steps "$REPRO_ENV_STEPS")
    # shellcheck disable=SC2086
    timeout "${REPRO_SECONDS:-540}" "${TS[@]}" reproduce --backend warp --device "$DEVICE" --algos sac \
        --seeds ${REPRO_SEEDS:-0 1 2} --no-progress "${REPRO_ARGS[@]}" --out /tmp/reproduce | tee "$OUT/reproduce.txt"
    rc=${PIPESTATUS[0]}
    for f in reproduce.json REPRODUCTION.md contest/contest.json evaluation/per_seed.csv; do
        cp -f "/tmp/reproduce/$f" "$OUT/" 2>/dev/null
    done
    for side in ant spider; do cp -f "/tmp/reproduce/$side/screens.json" "$OUT/screens-$side.json" 2>/dev/null; done
    echo "[$(elapsed) s] reproduce --backend warp: rc $rc"
    exit "$rc"
fi

# 2. time to skill on the device: SAC Bug, N_ENVS matches, evaluations in the background on the CPU (its device
#    reference collection compiles Warp's kernels, cached in ~/.cache/warp for step 3)
if [ "${QUICK:-0}" = "1" ]; then
    SKILL_ARGS=(--quick --device "$DEVICE")
else
    # shellcheck disable=SC2206
    SKILL_ARGS=(--device "$DEVICE" --n-envs "$N_ENVS" --max-seconds "$SKILL_SECONDS" --seeds $SEEDS
                --eval-threads 1 --eval-workers "$(( $(nproc) > 10 ? 8 : 1 ))")
fi
timeout $(( (SKILL_SECONDS + 120) * $(wc -w <<< "$SEEDS") )) "${TS[@]}" bench skill-gpu "${SKILL_ARGS[@]}" --out /tmp/skill-gpu \
    --json "$OUT/skill_gpu.json" | tee "$OUT/skill_gpu.txt"
rc=${PIPESTATUS[0]}
cp -f /tmp/skill-gpu/skill_gpu.png "$OUT/" 2>/dev/null
echo "[$(elapsed) s] bench skill-gpu: rc $rc"
# every seed's own evaluations, one file with the seed first (they survive a run stopped before its record)
for f in /tmp/skill-gpu/*/seed*/eval.csv; do
    [ -e "$f" ] || continue
    seed=$(basename "$(dirname "$f")"); seed=${seed#seed}
    [ -e "$OUT/evals.csv" ] || sed -n '1s/^/seed,/p' "$f" > "$OUT/evals.csv"
    sed -n "2,\$s/^/$seed,/p" "$f" >> "$OUT/evals.csv"
done

# 3. the Warp env benchmark, in the time left of TOTAL_SECONDS
if [ "${QUICK:-0}" = "1" ]; then ENV_SIZES=2; ENV_ARGS=(--steps 4 --rounds 1); else ENV_ARGS=(--steps 100 --rounds 2); fi
left=$(( TOTAL_SECONDS - $(elapsed) ))
if [ "$left" -ge 45 ]; then
    timeout "$left" "${TS[@]}" bench env --backend warp --device "$DEVICE" --num-envs "$ENV_SIZES" "${ENV_ARGS[@]}" \
        --json "$OUT/env_warp.json" | tee "$OUT/env_warp.txt"
    echo "[$(elapsed) s] bench env --backend warp: rc ${PIPESTATUS[0]}"
else
    echo "[$(elapsed) s] bench env --backend warp: skipped, $left s left of $TOTAL_SECONDS"
fi
exit "$rc"
