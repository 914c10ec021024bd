"""``rapidds train-policy`` and ``rapidds sample``: the robot's trajectory diffusion policy.

``train-policy`` fits a policy on a demonstrations ``.npz`` and writes a checkpoint directory;
``sample`` draws trajectories for one task, optionally steered by SVDD-PM away from people
standing on given paths (V = completion time + gamma * max_i S_i, the paper's value).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from rapidds.cli import app, fail
from rapidds.cli._device import check_optional_device
from rapidds.cli._options import AS_JSON, describe
from rapidds.cli._progress import progress
from rapidds.errors import RapiddsError
from rapidds.loop.config import DEVICE_HELP

if TYPE_CHECKING:  # imported where used: `rapidds --help` does not pay for numpy
    import numpy as np

    from rapidds.motion.policy import DiffusionPolicy


def _world_demos(name: str, per_mode: int, seed: int) -> tuple[Any, dict[str, Any]]:
    """A registered world's demonstrations (every motion mode of every robot task) and its
    network defaults."""
    import numpy as np

    from rapidds.motion.config import ConfigError
    from rapidds.motion.demos import Demonstrations
    from rapidds.worlds.registry import make_world

    if per_mode < 1:
        raise ConfigError(f"--demos-per-mode must be >= 1, got {per_mode}")
    world = make_world(name)
    d = world.robot_demonstrations(per_mode, np.random.default_rng(seed))
    demos = Demonstrations(d.trajectories.astype(np.float32), d.task_index, d.task_names)
    return demos, dict(world.policy_defaults)


def _bag_demos(name: str, path: Path, robot: str | None = None,
               mapping: Path | None = None) -> tuple[Any, dict[str, Any]]:
    """A world's robot demonstrations recorded in bags (ROS 2 or ROS 1), or as end-effector
    poses with task labels in a CSV (through the world's IK), and its network defaults."""
    from rapidds.bridge.poses import pose_demonstrations
    from rapidds.bridge.recorded import load_mapping, robot_demonstrations
    from rapidds.cli.bridge import log_to_stderr
    from rapidds.motion.demos import Demonstrations
    from rapidds.worlds.registry import make_world

    log_to_stderr()
    world = make_world(name)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return pose_demonstrations(path, world), dict(world.policy_defaults)
    if suffix == ".npz":
        return Demonstrations.load(path), dict(world.policy_defaults)
    if path.is_file() and suffix not in (".mcap", ".db3", ".bag"):
        raise RapiddsError(f"{path} is not demonstrations {name} reads: bags (.mcap, .db3, "
                           "ROS 1 .bag, bag folders), a CSV of end-effector poses, or an .npz")
    maps = None if mapping is None else load_mapping(mapping).check(world)
    return robot_demonstrations(path, world, maps, robot), dict(world.policy_defaults)


def _not_npz(path: Path) -> str | None:
    """What ``path`` is when it is not a demonstrations .npz that needs no world, in one line."""
    if path.suffix.lower() == ".csv":
        return (f"{path} is a CSV: end-effector poses with task labels become joint paths "
                "through a world's IK; add --world NAME")
    if path.suffix.lower() in (".bag", ".mcap", ".db3") or (path / "metadata.yaml").is_file():
        return f"{path} is a bag: its joint states are cut into tasks for a world; add --world"
    if path.is_file():
        with path.open("rb") as f:
            if f.read(4) != b"PK\x03\x04":
                return (f"{path} is not a demonstrations .npz (a NumPy zip archive); give an "
                        ".npz, or with --world a CSV of end-effector poses or bags")
    return None


@app.command("train-policy")
def train_policy_cmd(
    out: Annotated[Path, typer.Option("--out", help="Checkpoint directory to write.")],
    demos: Annotated[Path | None, typer.Option(
        "--demos", help="Demonstrations .npz (trajectories, task_index, task_names[, start]); "
        "with --world, bags of the robot (rosbag2 or ROS 1 .bag, or a folder of them: "
        "JointState cut into tasks by its task events), or a CSV of end-effector poses "
        "(x,y,z,qx,qy,qz,qw and one 0/1 column per task) through the world's IK.")
    ] = None,
    robot: Annotated[str | None, typer.Option(
        "--robot", help="With --world --demos BAGS: the robot profile naming the joint states' "
        "joints.", show_default="the first profile whose joints the bag carries")] = None,
    mapping: Annotated[Path | None, typer.Option(
        help="With --world --demos BAGS: a tracker mapping YAML whose 'boundaries' rules cut "
        "tasks from the cell's own signals.")] = None,
    world: Annotated[str | None, typer.Option(
        help="Train on a registered world's generated demonstrations instead (see 'rapidds "
        "worlds'), with the world's network defaults; with --demos, on its recorded ones.")
    ] = None,
    demos_per_mode: Annotated[int, typer.Option(
        help="With --world: demonstrations per task and route.")] = 64,
    steps: Annotated[int | None, typer.Option(
        help="Optimiser steps.", show_default="the config's")] = None,
    epochs: Annotated[int | None, typer.Option(
        help="Passes over the data (overrides --steps).")] = None,
    seed: Annotated[int | None, typer.Option(
        help="Seed for init, batches and noise.", show_default="the config's")] = None,
    device: Annotated[str | None, typer.Option(
        help="Where the network trains: auto (a CUDA GPU when one is available, else the CPU), "
        "cpu or cuda.", show_default="auto", callback=check_optional_device)] = None,
    horizon: Annotated[int | None, typer.Option(
        help="Resample demonstrations to H points (a multiple of 8) first.")] = None,
    batch_size: Annotated[int | None, typer.Option(help="Trajectories per step.")] = None,
    lr: Annotated[float | None, typer.Option(help="AdamW learning rate.")] = None,
    start_conditioned: Annotated[bool | None, typer.Option(
        "--start-conditioned/--no-start-conditioned",
        help="Condition on the start pose.", show_default="when the file has 'start'")] = None,
    config: Annotated[Path | None, typer.Option(
        "--config", help="JSON file of DiffusionConfig fields (network size, sampler, ...); "
        "flags win.")] = None,
    teacher: Annotated[Path | None, typer.Option(
        help="Distil this policy checkpoint: learn its noise predictions on the "
        "demonstrations, with its settings and normaliser unless --config or flags change "
        "them (a smaller network: --config with smaller down_dims).")] = None,
) -> None:
    """Train a trajectory diffusion policy on demonstrations and save a checkpoint."""
    from rapidds.motion.config import ConfigError, DiffusionConfig
    from rapidds.motion.demos import Demonstrations
    from rapidds.motion.train import total_steps, train_policy
    from rapidds.settings import read_yaml

    try:
        if demos is None and world is None:
            raise ConfigError("give --demos FILE, --world NAME, or --world NAME --demos BAGS")
        fields: dict[str, Any] = {}
        if world is not None and demos is not None:
            data, fields = _bag_demos(world, demos, robot, mapping)
            if horizon is not None:
                data = data.resample(horizon)
        elif world is not None:
            data, fields = _world_demos(world, demos_per_mode, 0 if seed is None else seed)
            if horizon is not None:
                data = data.resample(horizon)
        else:
            assert demos is not None
            if (foreign := _not_npz(demos)) is not None:
                raise ConfigError(foreign)
            data = Demonstrations.load(demos, horizon=horizon)
        mentor = None
        if teacher is not None:
            from rapidds.motion.policy import DiffusionPolicy
            mentor = DiffusionPolicy.load(teacher, device="cpu")
            fields.update(mentor.config.to_dict())
        if config is not None:
            fields.update(read_yaml(config, "config file"))  # JSON is YAML
        fields.update(horizon=data.horizon, state_dim=data.state_dim,
                      task_names=list(data.task_names))
        fields.setdefault("start_conditioned", data.start is not None)
        flags = {"steps": steps, "epochs": epochs, "seed": seed, "device": device,
                 "batch_size": batch_size, "lr": lr, "start_conditioned": start_conditioned}
        fields.update({k: v for k, v in flags.items() if v is not None})
        if epochs is None and steps is not None:
            fields["epochs"] = None
        cfg = DiffusionConfig.from_dict(fields)
        n_steps = total_steps(len(data), cfg)
        smooth: list[float] = []

        with progress("training", n_steps) as update:
            def on_step(step: int, loss: float) -> None:
                smooth.append(loss)
                del smooth[:-50]
                update(step, f"loss {sum(smooth) / len(smooth):.4f}")

            policy, history = train_policy(data, cfg, progress=on_step, teacher=mentor)
        where = policy.save(out)
    except RapiddsError as exc:
        fail(str(exc))
        return
    typer.echo(f"wrote policy to {where} ({history.steps} steps on {history.device}, "
               f"{history.seconds:.1f} s, final loss {history.mean_loss(last=50):.4f})")


def _check_batch(policy: Any, n: int, candidates: int) -> None:
    """Refuse -n x --candidates rows whose network activations would not fit in memory."""
    from rapidds.settings import require_memory

    cfg = policy.config
    require_memory(4 * 4 * max(cfg.down_dims) * n * candidates * cfg.horizon,
                   "-n x --candidates trajectories per network pass")


def _parse_path(spec: str, d: int, option: str = "--steer-cost") -> np.ndarray:
    import numpy as np

    """'x,y;x,y;...' -> (P, d) points (one person's path, or one pose)."""
    from rapidds.motion.config import ConfigError

    try:
        pts = np.array([[float(v) for v in p.split(",")] for p in spec.split(";") if p.strip()])
    except ValueError:
        raise ConfigError(f"{option} {spec!r}: expected points 'x,y;x,y;...'") from None
    if pts.ndim != 2 or pts.shape[0] == 0 or pts.shape[1] != d or not np.isfinite(pts).all():
        raise ConfigError(f"{option} {spec!r}: every point needs {d} finite coordinates")
    return pts


def _picture(path: Path, samples: np.ndarray, bounds: np.ndarray, people: list[np.ndarray],
             beta: float, title: str) -> Path:
    """Samples drawn over the workspace, on a heat map of the steering cost when there is one."""
    import numpy as np

    from rapidds.motion.steering import proximity_cost
    from rapidds.plots._mpl import plt, save
    from rapidds.plots.maps import plot_paths

    (x0, y0), (x1, y1) = bounds[0, :2], bounds[1, :2]
    fig, ax = plt.subplots(figsize=(5, 4.5))
    if people and samples.shape[-1] == 2:
        gx, gy = np.meshgrid(np.linspace(x0, x1, 160), np.linspace(y0, y1, 160))
        grid = np.stack([gx.ravel(), gy.ravel()], -1)[:, None, :]   # (G, 1, 2) one-point paths
        heat = np.max([proximity_cost(p, beta)(grid) for p in people], axis=0)
        im = ax.imshow(heat.reshape(gx.shape), origin="lower", extent=(x0, x1, y0, y1),
                       cmap="magma", vmin=0, vmax=1, aspect="equal")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="spatial cost")
        for p in people:
            ax.plot(p[:, 0], p[:, 1], "-o", color="tab:red", ms=3, lw=1, label="person")
    plot_paths(ax, samples, color="cyan" if people else "C0", alpha=0.8)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(title)
    return save(fig, path)


def _sample_in_world(
    world_name: str, policy_dir: Path | None, task: str, n: int, seed: int,
    concurrent: list[str], spatial_file: Path | None, gamma: float, candidates: int,
    alpha: float, as_json: bool, out: Path | None,
) -> None:
    """Samples in a registered world: V = the world's completion time + gamma * max over the
    concurrent human tasks of their spatial cost (population prior, or a saved person's model),
    drawn over that cost as a heat map with the walls (paper Figure 3 style)."""
    from functools import partial

    import numpy as np
    import torch

    from rapidds.human.spatial import SpatialModel
    from rapidds.loop.config import RunConfig
    from rapidds.loop.model import prior_model, workspace_cost
    from rapidds.loop.run import load_policy
    from rapidds.motion.steering import SteerRequest, steer
    from rapidds.plots.maps import save_cost_maps
    from rapidds.worlds.registry import make_world

    torch.set_num_threads(1)
    world = make_world(world_name)
    policy = load_policy(world, policy_dir)
    _check_batch(policy, n, candidates)
    if task not in policy.task_names:
        fail(f"task '{task}' is not one of the policy's tasks {list(policy.task_names)}")
    spatial = (SpatialModel.load(spatial_file) if spatial_file is not None
               else prior_model(world, RunConfig(world=world_name).resolved(world)).spatial)
    unknown = [t for t in concurrent if t not in spatial]
    if unknown:
        fail(f"no spatial model for human task(s) {unknown}; known: {list(spatial.tasks)}")
    cost = workspace_cost(world, spatial)

    def value(xi: np.ndarray) -> np.ndarray:
        v = world.completion_time(task, xi)
        return v + gamma * cost(concurrent, xi) if concurrent else v

    result = steer(policy, SteerRequest(task, n), value,
                   num_candidates=candidates if concurrent else 1, alpha=alpha, generator=seed)
    trajs = result.trajectories
    durations = world.completion_time(task, trajs)
    costs = cost(concurrent, trajs)
    routes = [world.motion_label(task, x) for x in trajs]
    if out is not None:
        shown = concurrent or list(spatial.tasks)
        tool = world.robot_points(trajs)[..., -1, :]  # the last body point is the tool
        save_cost_maps({t: spatial[t] for t in shown}, out, paths={t: tool for t in shown},
                       scene=partial(world.draw, view=next(iter(world.views))),
                       titles={t: f"robot {task} {'steered away from' if concurrent else 'over'}"
                               f" human {t}" for t in shown})
    if as_json:
        typer.echo(json.dumps({
            "world": world_name, "task": task, "n": n, "seed": seed, "concurrent": concurrent,
            "gamma": gamma, "candidates": candidates if concurrent else 1,
            "durations": durations.tolist(), "spatial": costs.tolist(), "routes": routes,
            "values": result.values.tolist(), "trajectories": trajs.tolist(),
            "picture": None if out is None else str(out),
        }, allow_nan=False))
        return
    counts = {r: routes.count(r) for r in sorted(set(routes))}
    typer.echo(f"{n} samples of robot task {task}" + (f" beside human {', '.join(concurrent)}"
               if concurrent else "") + f": routes {counts}, completion "
               f"{np.median(durations):.2f} s (median), spatial cost {np.median(costs):.2f}")
    if out is not None:
        typer.echo(f"wrote picture to {out}")


@app.command("sample")
def sample_cmd(
    task: Annotated[str, typer.Option("--task", help="Task name the policy was trained on.")],
    policy_dir: Annotated[Path | None, typer.Option(
        "--policy", help="Checkpoint directory; with --world also one the world ships by name "
        "('paper', the default, or painting's 'distilled').")
    ] = None,
    world: Annotated[str | None, typer.Option(
        help="Sample in a bundled world (fetch): its completion time and human spatial costs.")
    ] = None,
    concurrent: Annotated[str | None, typer.Option(
        help="With --world: human tasks running meanwhile, e.g. 't2' or 't2,t0'; steering keeps "
        "away from where this person is expected.")] = None,
    spatial: Annotated[Path | None, typer.Option(
        help="With --world: a saved person's spatial model (default: the population prior).")
    ] = None,
    n: Annotated[int, typer.Option("-n", "--n", min=1, max=1_000_000,
                                   help="Number of trajectories.")] = 8,
    seed: Annotated[int, typer.Option(min=0, max=2**63 - 1,
                                      help="Sampling seed (same seed, same samples).")] = 0,
    start: Annotated[str | None, typer.Option(
        help="Start pose 'x,y,...' for start-conditioned policies.")] = None,
    steer_cost: Annotated[list[str] | None, typer.Option(
        "--steer-cost", help="Steer away from a person on this path 'x,y;x,y;...' "
        "(repeatable: the maximum over people counts).")] = None,
    gamma: Annotated[float, typer.Option(help="Weight of the spatial cost in V.")] = 1.75,
    beta: Annotated[float, typer.Option(
        help="Distance decay of the spatial cost exp(-beta * distance).")] = 1.0,
    candidates: Annotated[int, typer.Option(min=1, max=4096,
        help=describe("candidates"))] = 8,
    alpha: Annotated[float, typer.Option(
        help="SVDD-PM temperature; 0 keeps the best candidate.")] = 0.0,
    tol: Annotated[float | None, typer.Option(
        help="Arrival tolerance of the completion time.",
        show_default="10% of the workspace extent")] = None,
    dt: Annotated[float, typer.Option(
        help="Seconds per trajectory point (completion time).")] = 1.0,
    device: Annotated[str | None, typer.Option(
        help=DEVICE_HELP, show_default="auto", callback=check_optional_device)] = None,
    as_json: bool = AS_JSON,
    out: Annotated[Path | None, typer.Option(
        "--out", help="Write a picture (PNG) of the samples.")] = None,
) -> None:
    """Sample trajectories for one task, optionally steered away from people (SVDD-PM)."""
    for name, v in (("--gamma", gamma), ("--alpha", alpha)):
        if not (math.isfinite(v) and v >= 0):
            fail(f"{name} must be a finite number >= 0, got {v}")
    if world is not None:
        given = [o for o, v in (("--steer-cost", steer_cost), ("--start", start)) if v]
        if given:  # a world steers by its person's spatial model and starts at its own pose
            fail(f"{' and '.join(given)} only without --world; with --world the person comes "
                 "from --concurrent and --spatial")
        tasks = [t for t in (concurrent or "").split(",") if t]
        _sample_in_world(world, policy_dir, task, n, seed, tasks, spatial, gamma, candidates,
                         alpha, as_json, out)
        return
    if policy_dir is None:
        fail("--policy is required without --world")
        return
    _sample_from_checkpoint(policy_dir, task, n, seed, start, steer_cost or [], gamma, beta,
                            candidates, alpha, tol, dt, device, as_json, out)


def _sample_from_checkpoint(
    policy_dir: Path, task: str, n: int, seed: int, start: str | None, steer_cost: list[str],
    gamma: float, beta: float, candidates: int, alpha: float, tol: float | None, dt: float,
    device: str | None, as_json: bool, out: Path | None,
) -> None:
    """``sample`` without a world: a checkpoint, people given as paths, the completion time
    with a tolerance."""
    import numpy as np

    from rapidds.motion.config import ConfigError
    from rapidds.motion.policy import DiffusionPolicy
    from rapidds.motion.steering import (
        completion_index,
        proximity_cost,
        value_function,
    )

    for name, v in (("--beta", beta), ("--dt", dt), ("--tol", tol)):
        if v is not None and not (math.isfinite(v) and v > 0):
            fail(f"{name} must be a finite number > 0, got {v}")
    try:
        policy = DiffusionPolicy.load(policy_dir, device=device)
        _check_batch(policy, n, candidates)
        cfg = policy.config
        if start is not None and ";" in start:
            raise ConfigError(f"--start {start!r}: give one pose 'x,y,...'")
        start_arr = None if start is None else _parse_path(start, cfg.state_dim, "--start")[0]
        if out is not None and cfg.state_dim < 2:
            raise ConfigError("--out draws paths of d >= 2 (first two coordinates)")
        norm = policy.normalizer
        extent = float(np.max(norm.high - norm.low)) or 1.0
        tol_v = 0.1 * extent if tol is None else tol
        people = [_parse_path(s, cfg.state_dim) for s in steer_cost]
        value_fn = value_function([proximity_cost(p, beta) for p in people], gamma, tol=tol_v,
                                  dt=dt)
        trajs, values, passes = _draw_samples(policy, task, n, value_fn, bool(people),
                                              candidates, alpha, start_arr, seed)
        if out is not None:
            pad = 0.1 * extent
            pts = np.concatenate([trajs.reshape(-1, cfg.state_dim), *people], axis=0)
            bounds = np.stack([np.minimum(norm.low, pts.min(0)) - pad,
                               np.maximum(norm.high, pts.max(0)) + pad])
            title = f"{task}: {n} {'steered ' if people else ''}samples"
            _picture(out, trajs, bounds, people, beta, title)
    except RapiddsError as exc:
        fail(str(exc))
        return

    completion = completion_index(trajs, tol_v)
    if not as_json:
        _print_samples(task, trajs, values, completion * dt, passes, bool(people), out)
        return
    typer.echo(json.dumps({
        "policy": str(policy_dir), "task": task, "n": n, "seed": seed,
        "steered": bool(people), "gamma": gamma, "beta": beta, "tol": tol_v, "dt": dt,
        "candidates": candidates if people else 1, "network_passes": passes,
        "completion_index": completion.tolist(), "values": values.tolist(),
        "trajectories": trajs.tolist(), "picture": None if out is None else str(out),
    }, allow_nan=False))


def _draw_samples(policy: DiffusionPolicy, task: str, n: int, value_fn: Any, steered: bool,
                  candidates: int, alpha: float, start: np.ndarray | None, seed: int
                  ) -> tuple[np.ndarray, np.ndarray, int]:
    """``n`` trajectories (steered by ``value_fn`` or plain), their values V and the network
    passes one sample took."""
    from rapidds.motion.config import ConfigError, cpu_threads
    from rapidds.motion.steering import SteerRequest, require_finite, steer

    cfg = policy.config
    threads = cpu_threads(cfg.cpu_threads if policy.device.type == "cpu" else 0)
    if not steered:
        with threads:
            trajs = require_finite(policy.sample(task, n, start=start, generator=seed))
        return trajs, value_fn(trajs), cfg.num_inference_steps
    if cfg.sampler == "ddim" and cfg.ddim_eta == 0 and candidates > 1:
        raise ConfigError("this policy samples with deterministic DDIM (ddim_eta = 0); "
                          "SVDD steering needs a stochastic sampler")
    with threads:
        result = steer(policy, SteerRequest(task, n, start), value_fn,
                       num_candidates=candidates, alpha=alpha, generator=seed)
    return result.trajectories, result.values, result.stats.network_passes


def _print_samples(task: str, trajs: np.ndarray, values: np.ndarray, completion_s: np.ndarray,
                   passes: int, steered: bool, out: Path | None) -> None:
    """The samples as a table: completion time, path length, end point and V of each."""
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    n = len(trajs)
    table = Table(title=f"{n} {'steered ' if steered else ''}samples of task {task!r}")
    for col in ("#", "completion (s)", "path length", "end", "V"):
        table.add_column(col, justify="right")
    lengths = np.linalg.norm(np.diff(trajs, axis=1), axis=-1).sum(axis=1)
    for k in range(n):
        end = ", ".join(f"{v:.2f}" for v in trajs[k, -1])
        table.add_row(str(k), f"{completion_s[k]:.1f}", f"{lengths[k]:.3f}", f"({end})",
                      f"{values[k]:.3f}")
    Console(width=100).print(table)
    typer.echo(f"mean V {np.mean(values):.3f} ({passes} network passes per sample)")
    if out is not None:
        typer.echo(f"wrote picture to {out}")
