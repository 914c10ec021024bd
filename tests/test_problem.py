"""Problem files: the documented format is accepted, every bad input is one clear ProblemError."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.core import TyperGroup
from typer.testing import CliRunner

from rapidds.cli import _register, app
from rapidds.errors import ProblemError, RapiddsError
from rapidds.problem import Objective, load_problem, problem_from_dict

ROOT = Path(__file__).resolve().parents[1]

ISSUE_EXAMPLE = """\
name: fetch
tasks:
  - id: t0
    allowed: [human, robot]
    human: {mean: 12.0, std: 2.0}
    robot: {duration: 13.0}
  - id: t1
    allowed: [human, robot]
    human: {mean: 12.0, std: 2.0}
    robot: {duration: 13.0}
  - id: t2
    allowed: [human, robot]
    human: {mean: 8.0, std: 1.5}
    robot: {duration: 9.0}
  - id: t3
    allowed: [human, robot]
    human: {mean: 8.0, std: 1.5}
    robot: {duration: 9.0}
precedence:
  - [t2, t0]
  - [t2, t1]
  - [t3, t0]
  - [t3, t1]
objective: {gamma: 1.75, lambda: 0.0}
"""

# The problem file exactly as the first specification of the file format gives it.
ISSUE_LITERAL = """\
name: four-fetch
tasks:
  - id: t0
    allowed: [human, robot]      # optional, default both
    human: {mean: 10.0, std: 2.0}  # prior on the human's duration in seconds; std 0 = deterministic
    robot: {duration: 8.0}       # nominal robot duration in seconds
  - id: t1
    allowed: [robot]
    robot: {duration: 4.0}       # human block may be left out when the human cannot do the task
precedence:
  - [t1, t0]                     # t1 must finish before t0 starts
objective: {gamma: 1.75, lambda: 0.0}   # optional
"""


def test_issue_literal_is_accepted(tmp_path):
    p = load_problem(_write(tmp_path, ISSUE_LITERAL, "four.yaml"))
    assert p.name == "four-fetch"
    assert p.task("t1").allowed == frozenset({"robot"})
    assert p.task("t1").human_mean is None
    assert p.task("t0").human_std == 2.0
    assert p.precedence == (("t1", "t0"),)


OK_TASK = "{id: a, human: {mean: 1}, robot: {duration: 1}}"


def _write(tmp_path: Path, text: str, name: str = "bad.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_issue_example_is_accepted(tmp_path):
    p = load_problem(_write(tmp_path, ISSUE_EXAMPLE, "fetch.yaml"))
    assert p.name == "fetch"
    assert p.ids == ("t0", "t1", "t2", "t3")
    assert p.precedence == (("t2", "t0"), ("t2", "t1"), ("t3", "t0"), ("t3", "t1"))
    assert p.objective == Objective(gamma=1.75, lam=0.0)
    t2 = p.task("t2")
    assert (t2.human_mean, t2.human_std, t2.robot_duration) == (8.0, 1.5, 9.0)
    assert t2.allowed == frozenset({"human", "robot"})
    assert p.predecessors("t0") == ("t2", "t3")
    # the dictionary form round-trips
    assert problem_from_dict(p.to_dict()) == p


@pytest.mark.parametrize("name", ["fetch", "painting", "painting-constrained", "random-8"])
def test_bundled_examples_load(name):
    p = load_problem(ROOT / "examples" / f"{name}.yaml")
    assert p.name == name
    assert len(p.tasks) >= 4


def test_painting_restrictions():
    p = load_problem(ROOT / "examples" / "painting.yaml")
    assert p.task("prep_vise").allowed == {"human"}
    assert p.task("secure_piece").allowed == {"human"}
    assert p.task("mix_l").allowed == p.task("mix_r").allowed == {"robot"}
    assert p.shared_tasks == ("brush",)
    assert set(p.predecessors("brush")) == {"mix_l", "mix_r", "secure_piece"}
    c = load_problem(ROOT / "examples" / "painting-constrained.yaml")
    assert ("mix_r", "mix_l") in c.precedence and ("mix_r", "mix_l") not in p.precedence


# (case id, file text, fragments the one-line message must contain)
BAD = [
    ("not-yaml", "tasks: [unclosed\n", ["not valid YAML", "line 2"]),
    ("tab-indent", "tasks:\n\t- id: a\n", ["not valid YAML"]),
    ("empty-file", "", ["expected a mapping"]),
    ("scalar", "42\n", ["expected a mapping", "int"]),
    ("list", "- a\n- b\n", ["expected a mapping", "list"]),
    ("no-tasks", "name: x\n", ["tasks", "Field required"]),
    ("empty-tasks", "tasks: []\n", ["tasks", "at least 1"]),
    ("tasks-mapping", "tasks: {a: 1}\n", ["tasks", "valid list"]),
    ("unknown-top-field", f"tasks: [{OK_TASK}]\ncolour: red\n", ["colour", "Extra inputs"]),
    ("unknown-task-field", "tasks: [{id: a, human: {mean: 1}, speed: 3}]\n",
     ["tasks[0] (id 'a').speed", "Extra inputs"]),
    ("unknown-prior-field", "tasks: [{id: a, human: {mean: 1, sd: 2}}]\n",
     ["tasks[0] (id 'a').human.sd"]),
    ("mean-not-number", "tasks: [{id: a, human: {mean: fast}}]\n",
     ["tasks[0] (id 'a').human.mean", "valid number"]),
    ("allowed-not-list", "tasks: [{id: a, allowed: human, human: {mean: 1}}]\n",
     ["tasks[0] (id 'a').allowed", "valid list"]),
    ("allowed-unknown-agent", "tasks: [{id: a, allowed: [alien], human: {mean: 1}}]\n",
     ["tasks[0] (id 'a').allowed[0]", "'human' or 'robot'"]),
    ("id-not-string", "tasks: [{id: 5, human: {mean: 1}, robot: {duration: 1}}]\n",
     ["tasks[0]", ".id", "valid string"]),
    ("id-empty", "tasks: [{id: '', human: {mean: 1}, robot: {duration: 1}}]\n",
     ["tasks[0].id", "at least 1 character"]),
    ("name-not-string", f"name: [x]\ntasks: [{OK_TASK}]\n", ["name", "valid string"]),
    ("precedence-not-list", f"tasks: [{OK_TASK}]\nprecedence: a\n", ["precedence"]),
    ("precedence-triple", f"tasks: [{OK_TASK}]\nprecedence: [[a, a, a]]\n", ["precedence[0]"]),
    ("objective-not-mapping", f"tasks: [{OK_TASK}]\nobjective: 3\n", ["objective"]),
    ("duplicate-ids", f"tasks: [{OK_TASK}, {OK_TASK}]\n", ["duplicate task id 'a'"]),
    ("precedence-unknown-id", f"tasks: [{OK_TASK}]\nprecedence: [[a, ghost]]\n",
     ["precedence[0]", "unknown task 'ghost'"]),
    ("precedence-self", f"tasks: [{OK_TASK}]\nprecedence: [[a, a]]\n",
     ["precedence[0]", "'a' cannot precede itself"]),
    ("precedence-cycle",
     "tasks: [" + ", ".join(OK_TASK.replace("id: a", f"id: {t}") for t in "abcd") + "]\n"
     "precedence: [[d, a], [a, b], [b, c], [c, a]]\n",
     ["precedence cycle", "a -> b -> c -> a"]),
    ("no-agent", "tasks: [{id: a, allowed: [], human: {mean: 1}}]\n",
     ["tasks[0] (id 'a').allowed", "at least 1 item"]),
    ("human-without-prior", "tasks: [{id: a, allowed: [human, robot], robot: {duration: 1}}]\n",
     ["task 'a'", "no 'human' prior"]),
    ("robot-without-duration", "tasks: [{id: a, allowed: [robot], human: {mean: 1}}]\n",
     ["task 'a'", "no 'robot' duration"]),
    ("negative-mean", "tasks: [{id: a, allowed: [human], human: {mean: -1}}]\n",
     ["tasks[0] (id 'a').human.mean", "> 0"]),
    ("zero-mean", "tasks: [{id: a, allowed: [human], human: {mean: 0}}]\n",
     ["human.mean", "> 0"]),
    ("negative-std", "tasks: [{id: a, allowed: [human], human: {mean: 1, std: -0.5}}]\n",
     ["human.std", ">= 0"]),
    ("nan-mean", "tasks: [{id: a, allowed: [human], human: {mean: .nan}}]\n",
     ["human.mean", "finite"]),
    ("inf-std", "tasks: [{id: a, allowed: [human], human: {mean: 1, std: .inf}}]\n",
     ["human.std", "finite"]),
    ("overflow-mean", "tasks: [{id: a, allowed: [human], human: {mean: 1.0e+400}}]\n",
     ["human.mean", "finite"]),
    ("negative-robot", "tasks: [{id: a, allowed: [robot], robot: {duration: -2}}]\n",
     ["robot.duration", "> 0"]),
    ("inf-robot", "tasks: [{id: a, allowed: [robot], robot: {duration: .inf}}]\n",
     ["robot.duration", "finite"]),
    ("nan-robot-second-task",
     f"tasks: [{OK_TASK}, {{id: b, allowed: [robot], robot: {{duration: .nan}}}}]\n",
     ["tasks[1] (id 'b').robot.duration", "finite"]),
    ("negative-gamma", f"tasks: [{OK_TASK}]\nobjective: {{gamma: -1}}\n", ["objective.gamma"]),
    ("nan-gamma", f"tasks: [{OK_TASK}]\nobjective: {{gamma: .nan}}\n", ["objective.gamma"]),
    ("inf-lambda", f"tasks: [{OK_TASK}]\nobjective: {{lambda: .inf}}\n",
     ["objective.lambda", "finite"]),
    ("python-tag", "tasks: !!python/object:os.system {}\n", ["not valid YAML"]),
]


@pytest.mark.parametrize(("case", "text", "fragments"), BAD, ids=[b[0] for b in BAD])
def test_bad_problem_file(tmp_path, case, text, fragments):
    path = _write(tmp_path, text)
    with pytest.raises(ProblemError) as info:
        load_problem(path)
    msg = str(info.value)
    assert isinstance(info.value, RapiddsError)
    assert msg.startswith(f"{path}: "), msg  # names the problem file
    assert "\n" not in msg
    for fragment in fragments:
        assert fragment in msg, msg


@pytest.mark.parametrize("value", ["true", "'5'"])
def test_wrongly_typed_numbers_are_rejected(tmp_path, value):
    path = _write(tmp_path, f"tasks: [{{id: a, allowed: [human], human: {{mean: {value}}}}}]\n")
    with pytest.raises(ProblemError, match=r"human\.mean"):
        load_problem(path)


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere.yaml"
    with pytest.raises(ProblemError, match=r"nowhere\.yaml: no such file"):
        load_problem(path)


def test_unreadable_file(tmp_path):
    with pytest.raises(ProblemError, match="cannot read"):
        load_problem(tmp_path)  # a folder
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfe\x00tasks")
    with pytest.raises(ProblemError, match=r"binary\.yaml: cannot read"):
        load_problem(binary)


def test_dict_errors_name_the_source():
    with pytest.raises(ProblemError, match=r"^my-job: tasks\[0\] \(id 'x'\)\.human\.mean"):
        problem_from_dict({"tasks": [{"id": "x", "human": {"mean": math.nan}}]}, "my-job")


# --- the command line: bad input is one line on stderr and exit code 2 ----------------------


def _plan_args(*args: str) -> list[str]:
    """argv for ``rapidds plan ARGS``. Typer collapses an app with a single command into that
    command, so while ``plan`` is the only one registered the word 'plan' is dropped."""
    _register()
    single = not isinstance(typer.main.get_command(app), TyperGroup)
    return list(args) if single else ["plan", *args]


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        (None, "no such file"),
        ("tasks: [unclosed\n", "not valid YAML"),
        (f"tasks: [{OK_TASK}]\nprecedence: [[a, a]]\n", "cannot precede itself"),
        ("tasks: [{id: a, allowed: [human], human: {mean: .nan}}]\n", "finite"),
    ],
)
def test_cli_bad_problem_is_one_line_exit_2(tmp_path, text, fragment):
    path = tmp_path / "bad.yaml"
    if text is not None:
        path.write_text(text)
    result = CliRunner().invoke(app, _plan_args(str(path), "--json"))
    assert result.exit_code == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("rapidds: error: ")
    assert "bad.yaml" in lines[0] and fragment in lines[0]
    assert "Traceback" not in result.stderr


def test_installed_entry_point_bad_problem(tmp_path):
    exe = Path(sys.executable).with_name("rapidds")
    # make install puts the console script beside the interpreter; its absence is a packaging bug
    assert exe.exists(), f"no rapidds entry point at {exe}"
    path = _write(tmp_path, "tasks: [{id: a, allowed: [], human: {mean: 1}}]\n")
    argv = _plan_args(str(path))
    proc = subprocess.run([str(exe), *argv], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("rapidds: error: ") and "allowed" in lines[0]
