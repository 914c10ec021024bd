"""Pictures of the painting cell: an RGB frame where an OpenGL backend exists (EGL here), a
one-line RenderError where none does; the rest of the world needs no OpenGL at all."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from rapidds.errors import RapiddsError
from rapidds.worlds.painting import PaintingWorld
from rapidds.worlds.painting.render import RenderError, render_cell, try_render_cell


def test_frame_or_clean_error() -> None:
    world = PaintingWorld(prior_people=4)
    traj = world.robot_trajectory("mix_l")
    dip = int(np.argmin(world.kinematics.tool(traj)[:, 2]))
    body = world.teammate("left-fast").nominal_path("secure_piece", 21)[5]
    img = try_render_cell(traj[dip], body, width=160, height=120)
    if img is None:  # no OpenGL backend on this machine: the error is one clean line
        with pytest.raises(RenderError) as err:
            render_cell(traj[dip], body, width=160, height=120)
        assert isinstance(err.value, RapiddsError) and "\n" not in str(err.value)
        return
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert img.std() > 10  # a scene, not a blank frame
    top = render_cell(traj[dip], body, width=160, height=120, camera="top")
    assert top.shape == img.shape and not np.array_equal(top, img)


def test_world_imports_without_mujoco_and_works_without_opengl() -> None:
    code = ("import sys, os; os.environ.pop('MUJOCO_GL', None); "
            "import rapidds.worlds.painting as p; assert 'mujoco' not in sys.modules; "
            "w = p.PaintingWorld(prior_people=4); "
            "t = w.completion_time('mix_l', w.robot_trajectory('mix_l')[None]); "
            "assert t[0] < w.penalty; assert 'MUJOCO_GL' not in os.environ; print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok"
