"""Offscreen pictures of the painting cell: the arm at a joint configuration, the person's hands
and forearms at given body points, rendered by MuJoCo into an RGB array.

Rendering is the only part of the painting world that needs an OpenGL backend. On machines
without a display MuJoCo renders through EGL (``MUJOCO_GL=egl``); this module selects EGL when
``MUJOCO_GL`` is unset, also when MuJoCo was already imported for the scene and its kinematics
(which do not need OpenGL). Where no backend works, :func:`render_cell` raises
:class:`RenderError`, one line, and :func:`try_render_cell` returns None.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.worlds.painting.scene import LAYOUT, CellLayout, load_model

__all__ = ["RenderError", "place_person", "render_cell", "try_render_cell"]


class RenderError(RapiddsError):
    """No OpenGL backend could render the painting cell here."""


def _renderer(model: object, height: int, width: int) -> object:
    """A ``mujoco.Renderer`` on EGL unless the user chose another backend."""
    if "mujoco" not in sys.modules:
        os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    chosen = os.environ.get("MUJOCO_GL", "").lower().strip()
    if chosen in ("disable", "disabled", "off", "false", "0"):
        raise RenderError(f"rendering is switched off (MUJOCO_GL={chosen})")
    if chosen not in ("", "egl"):
        return mujoco.Renderer(model, height, width)
    # MuJoCo picked its OpenGL backend when it was imported; GLFW, its default, needs a display
    # and aborts the process without one. Hand the renderer an EGL context instead.
    from mujoco import egl
    from mujoco.rendering.classic import gl_context

    previous = getattr(gl_context, "GLContext", None)
    gl_context.GLContext = egl.GLContext
    try:
        return mujoco.Renderer(model, height, width)
    finally:
        gl_context.GLContext = previous


def render_cell(q: Sequence[float] | np.ndarray | None = None,
                body: np.ndarray | None = None, *, width: int = 480, height: int = 360,
                camera: str = "overview", layout: CellLayout = LAYOUT) -> np.ndarray:
    """(height, width, 3) uint8 picture of the cell.

    q: (7,) arm joints (default: zeros, arm upright). body: (4, 3) the person's left hand, right
    hand, left elbow, right elbow (default: hands on the table's edge). camera: a camera of the
    scene ("overview"), or "top" for a view from above.
    """
    import mujoco

    from rapidds.worlds.painting.teammates import rest_points

    model = load_model(layout)
    data = mujoco.MjData(model)
    if q is not None:
        data.qpos[:7] = np.asarray(q, dtype=float).reshape(7)
    points = rest_points(layout) if body is None else np.asarray(body, dtype=float).reshape(4, 3)
    place_person(model, data, points)
    mujoco.mj_forward(model, data)
    try:
        renderer = _renderer(model, height, width)
    except RenderError:
        raise
    except Exception as exc:  # OpenGL failures surface as many types (ImportError, FatalError)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RenderError(f"cannot render the painting cell: {first}") from None
    try:
        if camera == "top":
            cam = mujoco.MjvCamera()
            cam.lookat[:] = (0.0, 0.15, 0.0)
            cam.distance, cam.azimuth, cam.elevation = 1.9, 90.0, -89.0
            renderer.update_scene(data, camera=cam)  # type: ignore[attr-defined]
        else:
            renderer.update_scene(data, camera=camera)  # type: ignore[attr-defined]
        return np.array(renderer.render())  # type: ignore[attr-defined]
    finally:
        renderer.close()  # type: ignore[attr-defined]


def try_render_cell(*args: object, **kwargs: object) -> np.ndarray | None:
    """:func:`render_cell`, or None where no OpenGL backend works."""
    try:
        return render_cell(*args, **kwargs)  # type: ignore[arg-type]
    except RenderError:
        return None


def place_person(model: object, data: object, points: np.ndarray) -> None:
    """Move the mocap hands to the hand points and the forearm capsules from elbow to hand."""
    import mujoco

    def mocap(name: str) -> int:
        return int(model.body_mocapid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)])

    for k, side in enumerate(("left", "right")):
        hand, elbow = points[k], points[2 + k]
        data.mocap_pos[mocap(f"{side}_hand")] = hand
        axis = hand - elbow
        axis = axis / max(float(np.linalg.norm(axis)), 1e-9)
        quat = np.zeros(4)
        # the capsule lies along the body's z axis: rotate z onto the forearm
        mujoco.mju_quatZ2Vec(quat, axis)
        i = mocap(f"{side}_forearm")
        data.mocap_pos[i] = elbow
        data.mocap_quat[i] = quat
