#!/usr/bin/env bash
# Builds .dev/site312.tar.xz: the packages rapidds's planning and training import that the lent
# GPU machine lacks (design notes, section 11: Python 3.12 with torch but no diffusers, MuJoCo,
# mink, OR-Tools, pydantic, ruckig), as cp312 manylinux wheels unpacked and xz-compressed (the
# wheels alone are 50 MB, over a device call's budget beside the tree), plus a stand-in
# gymnasium_robotics holding only the Franka Panda assets the painting world reads. The
# versions are this checkout's venv's. Then, from the repository root:
#     echo /.dev/ >> .git/info/exclude          # once: the payload never gets committed
#     run(carry=[".dev"], command="OUT=$OUT PYTHON=python3 PAYLOAD=.dev/site312.tar.xz \
#         bash benchmarks/gpu_check.sh")
set -euo pipefail
cd "$(dirname "$0")/.."
VENV_PY=${VENV_PY:-.venv/bin/python}
NAMES="diffusers mujoco mujoco-core glfw mink qpsolvers daqp ortools immutabledict protobuf
pydantic pydantic-core annotated-types typing-inspection typing-extensions ruckig
importlib-metadata"
pins=$("$VENV_PY" - $NAMES <<'PY'
import sys
from importlib.metadata import version
print(" ".join(f"{n}=={version(n)}" for n in sys.argv[1:]))
PY
)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
plat=""
for p in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64 \
         manylinux1_x86_64; do plat="$plat --platform $p"; done
# shellcheck disable=SC2086
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
    --implementation cp $plat -d "$work/wheels" $pins
# shellcheck disable=SC2086
python3 -m pip install -q --no-deps --no-index --no-compile --only-binary=:all: \
    --python-version 3.12 --implementation cp $plat --target "$work/site" "$work"/wheels/*.whl
assets=$("$VENV_PY" -c "from rapidds.worlds.painting.scene import franka_assets_dir as f; print(f())")
stand_in="$work/site/gymnasium_robotics/envs/assets/kitchen_franka"
mkdir -p "$stand_in"
cp -r "$assets" "$stand_in/"
echo '"""Stand-in: only the Franka Panda assets rapidds reads (GPU machine runs)."""' \
    > "$work/site/gymnasium_robotics/__init__.py"
mkdir -p .dev
tar cf - -C "$work/site" . | xz -T0 -9 > .dev/site312.tar.xz
ls -l .dev/site312.tar.xz
