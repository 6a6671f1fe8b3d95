#!/usr/bin/env bash
# The wheels benchmarks/gpu_check.sh installs on the GPU machine, fetched HERE (a machine with pip and PyPI).
#
# The GPU machine (one H200, python3 3.12 with torch) has no package index and lacks the simulation's packages:
# mujoco (+ mujoco-core, mujoco-studio, glfw, pyopengl), mujoco-warp, warp-lang, gymnasium (+ farama-notifications),
# pettingzoo and openskill. They travel as wheels in the device tool's `carry`, at most 64 MiB a call with the
# working tree, and warp-lang's wheel alone is 142 MiB. So this script cuts them into parts of at most PART_MIB
# (default 40) and lays them out one call each:
#
#     .whl/1/ .whl/2/ ...   every wheel, or a part of one (NAME.whl.part-NN), with SHA256SUMS in .whl/1
#
# Usage, from the repository root (once; `.whl/` is in .gitignore, so it travels only when carried):
#     bash benchmarks/gpu_wheels.sh                 # PART_MIB=40 PYTHON=python3 by default
# then one device call per folder but the last, in quick succession (a warm machine keeps /tmp between calls):
#     run(carry=[".whl/1"], command="bash benchmarks/gpu_check.sh stage")   ... for each but the last, then
#     run(carry=[".whl/N"], command="bash benchmarks/gpu_check.sh", timeout_s=560)
# (docs/gpu.md, "Time to skill on a GPU").
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
PART_MIB=${PART_MIB:-40}
# Pinned: the versions the Warp backend is tested with here (tests/test_warp_backend.py on Warp's CPU device).
WHEELS=(warp-lang==1.19.0 mujoco-warp==4.0.0 mujoco==4.0.0 mujoco-core==4.0.0 mujoco-studio==4.0.0 glfw==2.11.0
        pyopengl==3.1.10 gymnasium==1.2.2 farama-notifications==0.0.6 pettingzoo==1.27.0 openskill==6.2.0)
PLATFORMS=(--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64
           --platform manylinux2014_x86_64 --platform manylinux1_x86_64)

rm -rf .whl && mkdir -p .whl/all
for w in "${WHEELS[@]}"; do
    "$PYTHON" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        "${PLATFORMS[@]}" -d .whl/all "$w"
done
(cd .whl/all && sha256sum -- *.whl > ../SHA256SUMS)

limit=$((PART_MIB * 1024 * 1024))
mkdir -p .whl/parts
for f in .whl/all/*.whl; do  # big wheels in parts of PART_MIB, the others whole
    if [ "$(stat -c %s "$f")" -gt "$limit" ]; then
        split -d -a 2 -b "$limit" "$f" ".whl/parts/$(basename "$f").part-"
    else
        cp "$f" .whl/parts/
    fi
done
# fill the call folders, largest first, each up to PART_MIB
n=1; used=0; mkdir -p .whl/1
mv .whl/SHA256SUMS .whl/1/
while read -r size f; do
    if [ $((used + size)) -gt "$limit" ] && [ "$used" -gt 0 ]; then n=$((n + 1)); used=0; mkdir -p ".whl/$n"; fi
    mv "$f" ".whl/$n/"; used=$((used + size))
done < <(find .whl/parts -type f -printf '%s %p\n' | sort -rn)
rm -rf .whl/all .whl/parts
du -sh .whl/*
echo "$n device calls: carry .whl/1 .. .whl/$n, one each; every call but the last runs 'bash benchmarks/gpu_check.sh stage'"
