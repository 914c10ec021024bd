"""The painting cell as a MuJoCo scene: table, Franka Emika Panda, vise, paint trays, bowl and
the person's hands and forearms.

Robot model: the Panda MJCF shipped in the ``gymnasium-robotics`` wheel
(``gymnasium_robotics/envs/assets/kitchen_franka/franka_assets/``: ``chain.xml`` is the arm's
body tree, ``assets.xml`` its meshes and classes). Its header says it is modified from
vikashplus/franka (Vikash Kumar), licensed under the Apache License 2.0; the wheel itself is MIT.
It is used unchanged, included by absolute path: nq = 9 (7 arm joints + 2 finger slides), and
its joint 6 is offset by -pi/2 (range [-1.6573, 2.1127]) from Franka's usual convention.

Frame, in metres: the origin lies on the table top on the person's sagittal plane; x points to
the person's right, y away from the person towards the robot, z up. The cell is mirror-symmetric
about the plane x = 0 (left tray <-> right tray, left rack <-> right rack, left hand <-> right
hand), so a left-handed person is exactly the mirror image of a right-handed one. Top view::

      y
    0.70 +------------------------------------------+   table edge, robot side
         |                   [R]                    |   R: robot base (0, 0.58)
         |                   (B)                    |   B: mixing bowl (0, 0.24)
         |     [ L ]                      [ R ]     |   trays, centres (-/+0.38, 0.05)
         |     [tray]                     [tray]    |
         |  (rack)          [vise]          (rack)  |   vise (0, -0.10), racks (-/+0.40, -0.12)
   -0.35 +------------------------------------------+   table edge, person side
                   o  hands at rest  o                  hands (-/+0.16, -0.29)
               person, shoulders (-/+0.19, -0.55, 0.30)
       -0.75                 0                  0.75  x

The person's hands and forearms are mocap (kinematic) bodies: they are placed, never simulated.
Only rendering needs an OpenGL backend; building the model does not.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rapidds.errors import RapiddsError

if TYPE_CHECKING:
    import mujoco

__all__ = [
    "ARM_BODIES",
    "ARM_JOINTS",
    "LAYOUT",
    "Box",
    "CellLayout",
    "SceneError",
    "build_model",
    "franka_assets_dir",
    "load_model",
    "model_key",
]

ARM_JOINTS: tuple[str, ...] = tuple(f"robot:panda0_joint{k}" for k in range(1, 8))
ARM_BODIES: tuple[str, ...] = tuple(f"panda0_link{k}" for k in range(8))
HUMAN_BODIES: tuple[str, ...] = ("left_hand", "right_hand", "left_forearm", "right_forearm")
_ASSET_SUBDIR = ("envs", "assets", "kitchen_franka", "franka_assets")


class SceneError(RapiddsError):
    """The painting scene cannot be built: MuJoCo or the Panda assets are missing or corrupt."""


@dataclass(frozen=True)
class Box:
    """An axis-aligned box: centre (x, y, z) and half sizes, metres."""

    center: tuple[float, float, float]
    half: tuple[float, float, float]

    @property
    def lo(self) -> np.ndarray:
        return np.subtract(self.center, self.half)

    @property
    def hi(self) -> np.ndarray:
        return np.add(self.center, self.half)

    def mirrored(self) -> Box:
        """The box reflected in the plane x = 0."""
        return Box((-self.center[0], self.center[1], self.center[2]), self.half)


@dataclass(frozen=True)
class CellLayout:
    """Where everything stands (metres, the frame of the module docstring).

    table: the table top (its upper face is z = 0). robot_base: where link0 is mounted; the
    arm faces -y, towards the person. vise, workpiece, bowl, left_tray, left_rack: boxes; the
    right tray and rack are the mirror images. shoulders: the person's left shoulder (the right
    one is mirrored); upper_arm, forearm: segment lengths of the person's arms.
    """

    table: Box = Box((0.0, 0.175, -0.02), (0.75, 0.525, 0.02))
    robot_base: tuple[float, float, float] = (0.0, 0.58, 0.0)
    vise: Box = Box((0.0, -0.10, 0.04), (0.08, 0.05, 0.04))
    vise_handle: Box = Box((0.0, -0.19, 0.04), (0.012, 0.04, 0.012))
    workpiece: Box = Box((0.0, -0.10, 0.115), (0.06, 0.015, 0.035))
    bowl: Box = Box((0.0, 0.24, 0.03), (0.07, 0.07, 0.03))
    left_tray: Box = Box((-0.38, 0.05, 0.02), (0.07, 0.11, 0.02))
    left_rack: Box = Box((-0.40, -0.12, 0.02), (0.05, 0.04, 0.02))
    left_shoulder: tuple[float, float, float] = (-0.19, -0.55, 0.30)
    upper_arm: float = 0.30
    forearm: float = 0.28

    @property
    def right_tray(self) -> Box:
        return self.left_tray.mirrored()

    @property
    def right_rack(self) -> Box:
        return self.left_rack.mirrored()

    @property
    def right_shoulder(self) -> tuple[float, float, float]:
        x, y, z = self.left_shoulder
        return (-x, y, z)

    def obstacles(self) -> dict[str, Box]:
        """Every fixed object the arm must not touch (the table top is handled on its own)."""
        return {
            "vise": self.vise, "vise_handle": self.vise_handle, "workpiece": self.workpiece,
            "bowl": self.bowl, "left_tray": self.left_tray, "right_tray": self.right_tray,
            "left_rack": self.left_rack, "right_rack": self.right_rack,
        }


LAYOUT = CellLayout()


def franka_assets_dir() -> Path:
    """The Panda MJCF folder inside the installed ``gymnasium-robotics`` (found without
    importing the package, whose import prints a warning and pulls in gymnasium)."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or not spec.submodule_search_locations:
        raise SceneError("the painting world needs gymnasium-robotics (its Franka Panda model); "
                         "pip install gymnasium-robotics")
    return Path(next(iter(spec.submodule_search_locations))).joinpath(*_ASSET_SUBDIR)


def _wrapper_xml(assets: Path, base: tuple[float, float, float], actuators: bool = False) -> str:
    # Base rotated -90 deg about z: link0's +x (the arm's forward) points to -y, the person.
    x, y, z = base
    act = f'\n  <include file="{assets / "actuator.xml"}"/>' if actuators else ""
    return f"""<mujoco model="rapidds-painting">
  <include file="{assets / 'assets.xml'}"/>{act}
  <compiler angle="radian" meshdir="{assets / 'meshes'}"/>
  <option timestep="0.002"/>
  <worldbody>
    <light name="top" pos="0 0.1 2.0" dir="0 0 -1" diffuse="0.7 0.7 0.7"/>
    <camera name="overview" pos="1.3 -1.2 1.1" xyaxes="0.68 0.73 0 -0.35 0.33 0.88"/>
    <body name="robot_base" pos="{x} {y} {z}" quat="0.70710678118654757 0 0 -0.70710678118654757">
      <include file="{assets / 'chain.xml'}"/>
    </body>
  </worldbody>
</mujoco>"""


def build_model(layout: CellLayout = LAYOUT, assets: Path | None = None, *,
                physics: bool = False) -> mujoco.MjModel:
    """Compile the cell: the Panda from ``assets`` (default: the installed gymnasium-robotics
    copy) plus table, objects and the person's mocap hands and forearms. SceneError, one line,
    when MuJoCo or an asset is missing or unreadable.

    ``physics``: also the Panda's position actuators (the shipped ``actuator.xml``: its gains
    and force limits); the person's hands and forearms collide with the arm, so ``mj_step``
    runs the arm and its contacts report touches (a kinematic hand pushes the arm, as a real
    one would); the paint trays, the bowl and the workpiece do not (the tool dips into them)."""
    try:
        import mujoco
    except ImportError:
        raise SceneError("the painting world needs MuJoCo; pip install mujoco") from None
    folder = franka_assets_dir() if assets is None else Path(assets)
    for name in ("assets.xml", "chain.xml"):
        if not (folder / name).is_file():
            raise SceneError(f"Panda asset {folder / name} is missing")
    try:
        spec = mujoco.MjSpec.from_string(_wrapper_xml(folder, layout.robot_base, physics))
        if physics:
            _panda_fingers(spec)
        _add_cell(spec, layout, physics)
        model = spec.compile()
    except (ValueError, RuntimeError, OSError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SceneError(f"cannot build the painting scene from {folder}: {first}") from None
    missing = [j for j in ARM_JOINTS if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) < 0]
    if missing or model.nq != 9:
        raise SceneError(f"the Panda model in {folder} is not the expected one (nq = {model.nq}, "
                         f"missing joints: {', '.join(missing) or 'none'})")
    return model


def model_key(layout: CellLayout = LAYOUT) -> str:
    """A key for what :func:`load_model` compiles, found without compiling it (or importing
    MuJoCo): this module's source, the layout, the Panda's MJCF files (not its meshes, which
    move nothing) and MuJoCo's version. Caches of what the arm's kinematics give key on it.
    Read anew at each call (about a millisecond), so edited assets never meet a stale key."""
    from importlib.metadata import version

    from rapidds.cache import code_version, content_key

    folder = franka_assets_dir()
    files = sorted(folder.glob("*.xml"))
    return content_key(code_version(__file__), repr(layout), version("mujoco"),
                       *(x for f in files for x in (f.name, np.frombuffer(f.read_bytes(),
                                                                           np.uint8))))


@cache
def load_model(layout: CellLayout = LAYOUT) -> mujoco.MjModel:
    """:func:`build_model` compiled once per process and layout (about 0.2 s, mostly meshes)."""
    return build_model(layout)


FINGERS: tuple[str, ...] = ("panda0_leftfinger", "panda0_rightfinger")


def _panda_fingers(spec: mujoco.MjSpec) -> None:
    """The fingers at the Panda's own length, for ``mj_step``.

    The kitchen model stretches the finger mesh 1.75 times along the finger (``finger_viz``'s
    scale in assets.xml) and lays its finger collision capsules along the stretched finger, out
    to 0.26 m past link7, but keeps its ``end_effector`` site at the Panda's TCP (0.210 m: the
    flange's 0.107 plus Franka's 0.1034). The kinematic world takes that site as the tool tip
    and plans the tool down to 2 cm above the table in the trays; the stretched fingertips then
    reach 3 cm into the table top and hold the arm 2-3 cm short of every mix. Unstretched, the
    fingers end 1 cm past the TCP, as Franka's hand does, and the arm reaches what is planned."""
    stretch = float(spec.mesh("finger_viz").scale[2])
    spec.mesh("finger_viz").scale = [*spec.mesh("finger_viz").scale[:2], 1.0]
    for name in FINGERS:
        for g in spec.body(name).geoms:
            if not g.contype:  # the visual mesh (unstretched above)
                continue
            if np.isfinite(g.fromto[0]):  # a capsule from-to along the finger (its z)
                g.fromto = [v / stretch if i % 3 == 2 else v for i, v in enumerate(g.fromto)]
            else:
                g.pos = [g.pos[0], g.pos[1], g.pos[2] / stretch]
                g.size = [g.size[0], g.size[1], g.size[2] / stretch]


def _add_box(body: mujoco.MjsBody, name: str, box: Box, rgba: tuple[float, ...],
             collide: bool = True) -> None:
    import mujoco

    g = body.add_geom()
    g.name = name
    g.type = mujoco.mjtGeom.mjGEOM_BOX
    g.size = list(box.half)
    g.pos = list(box.center)
    g.rgba = list(rgba)
    g.contype = g.conaffinity = 1 if collide else 0


def _add_cell(spec: mujoco.MjSpec, layout: CellLayout, physics: bool = False) -> None:
    import mujoco

    world = spec.worldbody
    cell = world.add_body()
    cell.name = "cell"
    _add_box(cell, "table_top", layout.table, (0.62, 0.52, 0.40, 1.0))
    t = layout.table
    for sx in (-1, 1):
        for sy in (-1, 1):
            leg = Box((t.center[0] + sx * (t.half[0] - 0.04), t.center[1] + sy * (t.half[1] - 0.04),
                       -0.4), (0.025, 0.025, 0.36))
            _add_box(cell, f"table_leg_{'lr'[sx > 0]}{'fb'[sy > 0]}", leg, (0.45, 0.36, 0.27, 1))
    _add_box(cell, "vise", layout.vise, (0.35, 0.38, 0.42, 1.0))
    _add_box(cell, "vise_handle", layout.vise_handle, (0.2, 0.2, 0.22, 1.0))
    # Under physics the tool dips into the paint and brushes the piece, as the world's
    # completion rule has it (only the tool tip may enter them): these do not collide there.
    dip = not physics
    _add_box(cell, "workpiece", layout.workpiece, (0.85, 0.75, 0.55, 1.0), dip)
    _add_box(cell, "bowl", layout.bowl, (0.9, 0.9, 0.88, 1.0), dip)
    _add_box(cell, "left_tray", layout.left_tray, (0.15, 0.35, 0.8, 1.0), dip)
    _add_box(cell, "right_tray", layout.right_tray, (0.8, 0.25, 0.15, 1.0), dip)
    _add_box(cell, "left_rack", layout.left_rack, (0.5, 0.5, 0.5, 1.0))
    _add_box(cell, "right_rack", layout.right_rack, (0.5, 0.5, 0.5, 1.0))
    skin = (0.93, 0.76, 0.64, 1.0)
    for name in HUMAN_BODIES:
        b = world.add_body()
        b.name = name
        b.mocap = True
        g = b.add_geom()
        g.name = f"{name}_geom"
        # kinematic: shown, never pushed; under physics it touches (and pushes) the arm
        g.contype = g.conaffinity = 1 if physics else 0
        g.rgba = list(skin)
        if name.endswith("hand"):
            g.type = mujoco.mjtGeom.mjGEOM_ELLIPSOID
            g.size = [0.045, 0.06, 0.025]
        else:  # a capsule along the body's z axis, from the elbow (z = 0) to the hand
            g.type = mujoco.mjtGeom.mjGEOM_CAPSULE
            g.fromto = [0.0, 0.0, 0.0, 0.0, 0.0, layout.forearm]
            g.size = [0.035, 0.0, 0.0]
