"""Broken scenes and CLI calls: one `error:` line naming the key or file, exit 2.

Each case runs the real command line (`python -m pfem2x check|run ...`).
"""

import json
import subprocess
import sys

import pytest

from pfem2x import compat

GOOD = """
[scene]
name = "tiny"
[mesh]
kind = "rectangle"
bounds = [[0, 0], [1, 1]]
cells = [4, 4]
[effects]
advection = true
[transport]
velocity = ["1", "0"]
initial = "x"
[time]
t_end = 0.1
dt = 0.05
"""


def cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "pfem2x", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
    )


def assert_one_error(res, *needles):
    assert res.returncode == 2, (res.returncode, res.stderr)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("error:"), lines[0]
    assert "Traceback" not in res.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])


BROKEN = {
    "bad_toml": (GOOD.replace('name = "tiny"', "name = tiny ="), ["not valid TOML"]),
    "unknown_key": (
        GOOD.replace("t_end = 0.1", "t_end = 0.1\ncourrant = 3"),
        ["time.courrant", "time.courant"],
    ),
    "unknown_section": (GOOD + "\n[mesch]\nx = 1\n", ["mesch", "mesh"]),
    "wrong_type": (
        GOOD.replace("cells = [4, 4]", 'cells = ["a", 4]'),
        ["mesh.cells[0]", "integer"],
    ),
    "negative_dt": (GOOD.replace("dt = 0.05", "dt = -0.05"), ["time.dt"]),
    "partition_word": (
        GOOD.replace("cells = [4, 4]", 'cells = [4, 4]\npartition = "colums"'),
        ["mesh.partition", "columns"],
    ),
    "t_end_zero": (GOOD.replace("t_end = 0.1", "t_end = 0.0"), ["time.t_end"]),
    "zero_cells": (GOOD.replace("cells = [4, 4]", "cells = [0, 4]"), ["mesh.cells[0]"]),
    "dt_and_courant": (
        GOOD.replace("dt = 0.05", "dt = 0.05\ncourant = 2"),
        ["time.dt", "time.courant"],
    ),
    "import_in_expression": (
        GOOD.replace('initial = "x"', "initial = \"__import__('os')\""),
        ["transport.initial"],
    ),
    "attribute_in_expression": (
        GOOD.replace('initial = "x"', 'initial = "x.real"'),
        ["transport.initial", "attribute"],
    ),
    "dunder_name": (GOOD.replace('initial = "x"', 'initial = "__class__"'), ["transport.initial"]),
    "missing_mesh_file": (
        GOOD.replace('kind = "rectangle"', 'kind = "gmsh"\nfile = "nope.geo"'),
        ["mesh.file", "nope.geo"],
    ),
    "unknown_frame": (GOOD + '\n[method]\nframe = "lagrangain"\n', ["method.frame", "lagrangian"]),
    "negative_kappa": (
        GOOD.replace("advection = true", "advection = true\ndiffusion = true").replace(
            'initial = "x"', 'initial = "x"\nkappa = -1'
        ),
        ["transport.kappa"],
    ),
    "huge_particle_count": (
        GOOD.replace("cells = [4, 4]", "cells = [3000, 3000]")
        + "\n[method]\nframe = 'lagrangian'\nparticles_per_cell = 1000\n",
        ["method.particles_per_cell", "GiB"],
    ),
    "velocity_missing": (GOOD.replace('velocity = ["1", "0"]\n', ""), ["transport.velocity"]),
    "param_reserved": (GOOD + "\n[params]\nx = 1\n", ["params.x"]),
    "wrong_dim_bounds": (
        GOOD.replace("bounds = [[0, 0], [1, 1]]", "bounds = [[0], [1]]"),
        ["mesh.bounds"],
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_scene(case, tmp_path):
    text, needles = BROKEN[case]
    p = tmp_path / "scene.toml"
    p.write_text(text)
    assert_one_error(cli("check", str(p)), *needles)


def test_good_scene_checks(tmp_path):
    p = tmp_path / "scene.toml"
    p.write_text(GOOD)
    res = cli("check", str(p))
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("ok: tiny")
    assert "steps of dt = " in res.stdout


def test_adaptive_scene_check_names_the_courant_number(tmp_path):
    """``check`` of an adaptive step gives its first dt and the Courant number it follows."""
    p = tmp_path / "scene.toml"
    p.write_text(GOOD)
    res = cli("check", str(p), "--set", "time.courant=2", "--set", "time.adaptive=true")
    assert res.returncode == 0, res.stderr
    assert "re-evaluated every step from time.courant = 2" in res.stdout
    assert "steps of dt" not in res.stdout


def test_adaptive_with_a_fixed_step_is_refused(tmp_path):
    """``time.adaptive`` with ``time.dt`` (no Courant number to follow): one error line, not
    a silently fixed step; a later ``time.dt`` over a frame table's adaptive Courant step
    replaces both (docs/USAGE.md)."""
    p = tmp_path / "scene.toml"
    p.write_text(GOOD)
    assert_one_error(
        cli("check", str(p), "--set", "time.adaptive=true"), "time.adaptive", "time.courant"
    )
    res = cli(
        "check", "rising-bubble", "--set", 'method.frame="lagrangian"', "--set", "time.dt=0.05"
    )
    assert res.returncode == 0, res.stderr
    assert "60 steps of dt = 0.05" in res.stdout


def test_corrupt_gmsh_file(tmp_path):
    geo = tmp_path / "bad.geo"
    geo.write_text("Point(1) = {0, 0, 0\nthis is not gmsh {{{\n")
    p = tmp_path / "scene.toml"
    p.write_text(GOOD.replace('kind = "rectangle"', f'kind = "gmsh"\nfile = "{geo}"'))
    assert_one_error(cli("check", str(p)), "bad.geo")


def test_binary_scene_file(tmp_path):
    p = tmp_path / "scene.toml"
    p.write_bytes(b"\xff\xfe\x00garbage")
    assert_one_error(cli("check", str(p)), "scene.toml")


@pytest.mark.parametrize(
    "args, needles",
    [
        (["check", "no-such-scene"], ["no-such-scene"]),
        (["check", "gausian-hill"], ["gaussian-hill"]),
        (["check", "gaussian-hill", "--set", "time.courant"], ["--set", "KEY=VALUE"]),
        (["check", "gaussian-hill", "--set", "time.courant=[1,"], ["--set"]),
        (["check", "gaussian-hill", "--set", "time.courant=-3"], ["time.courant"]),
        (["check", "gaussian-hill", "--set", "mesh.cells=[0,10]"], ["mesh.cells[0]"]),
        (["check", "gaussian-hill", "--variant", "huge"], ["--variant", "small"]),
        (["check", "dam-break", "--set", 'flow.max_speed="1/0"'], ["flow.max_speed", "1/0"]),
        (["run", "dam-break", "--set", 'flow.max_speed="1/0"'], ["flow.max_speed", "1/0"]),
        (["check", "dam-break", "--set", 'flow.time_factor="1e308*10"'], ["flow.time_factor"]),
        (["run"], ["scene"]),
        (["frobnicate"], ["frobnicate"]),
        (["run", "gaussian-hill", "--bogus"], ["--bogus", "`pfem2x run --help`"]),
        (["--bogus"], ["`pfem2x --help`"]),
    ],
)
def test_bad_cli(args, needles):
    assert_one_error(cli(*args), *needles)


@pytest.mark.parametrize(
    "scene, key, expr",
    [
        ("gaussian-hill", "transport.initial", '"sqrt(x)"'),
        ("gaussian-hill", "transport.initial", '"log(x - 10)"'),
        ("taylor-green", "flow.initial_velocity", '["1/(x - x)", "0"]'),
        ("channel", "flow.inflow_velocity", '["1/(y - y)", "0"]'),
    ],
)
def test_initial_field_not_finite(scene, key, expr, tmp_path):
    """A NaN/Inf initial field is bad input (exit 2, the key named), not a blow-up (exit 3)."""
    out = tmp_path / "out"
    res = cli("run", scene, "--variant", "small", "--set", f"{key}={expr}", "--out", str(out))
    assert_one_error(res, key, "not finite")
    assert not out.exists()


@pytest.mark.parametrize("frame", ["eulerian", "lagrangian"])
def test_inflow_velocity_counts_on_the_inflow_side_only(frame, tmp_path):
    """``flow.inflow_velocity`` is used on the inflow side: NaN elsewhere (0/0 at the outflow
    side x = 4) changes nothing; the channel's own profile gives the same run to the bit."""
    f = f'method.frame="{frame}"'
    profile = "4*Um*y*(Hc - y)/Hc**2"
    errors = []
    for expr in (profile, f"{profile} + 0/(x - 4)"):
        out = tmp_path / str(len(errors))
        inflow = f'flow.inflow_velocity=["{expr}", "0"]'
        res = cli("run", "channel", "--variant", "small", "--set", f, "--set", inflow,
                  "--set", "output.png=false", "--out", str(out))  # fmt: skip
        assert res.returncode == 0, res.stderr
        summary = json.loads((out / "summary.json").read_text())
        errors.append(summary["metrics"]["velocity_l2_error_final"])
    if not compat.NEW_API:  # Debian's DOLFINx 0.5.2: the same run to the bit
        assert errors[0] == errors[1]
    else:
        # DOLFINx 0.11 (PyPI wheel): one process in about eight gives other last bits for
        # the same scene, the profile alone (0.011415612449999484 / ...505, 1.8e-15
        # relative; with every preconditioner Jacobi too): round-off. A value of the NaN
        # side used anywhere would make the metric NaN or move it far beyond that
        assert errors[1] == pytest.approx(errors[0], rel=1e-13, abs=0.0)


def test_existing_output_folder_untouched(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    keep = out / "precious.txt"
    keep.write_text("keep me")
    p = tmp_path / "scene.toml"
    p.write_text(GOOD)
    assert_one_error(cli("run", str(p), "--out", str(out), "--quiet"), str(out), "--overwrite")
    assert keep.read_text() == "keep me"
    assert sorted(x.name for x in out.iterdir()) == ["precious.txt"]


def test_step_override_replaces_the_scene_choice():
    from pfem2x.scene import SceneError, load_scene

    s = load_scene("gaussian-hill", ["time.dt=0.1"])
    assert s.time.dt == 0.1 and s.time.courant is None
    s = load_scene("gaussian-hill", ["time.courant=2"])
    assert s.time.courant == 2.0 and s.time.dt is None
    with pytest.raises(SceneError, match="exactly one"):
        load_scene("gaussian-hill", ["time.dt=0.1", "time.courant=2"])


UNSAFE_NAMES = {
    "slash": "a/b",
    "parent": "..",
    "dot": ".",
    "empty": "",
    "nul": "x\\u0000y",
    "long": "n" * 101,
    "escape": "../../../escape",
    "space": "a b",
    "backslash": "a\\\\b",
}


@pytest.mark.parametrize("case", sorted(UNSAFE_NAMES))
def test_unsafe_scene_name(case, tmp_path):
    p = tmp_path / "scene.toml"
    p.write_text(GOOD.replace('name = "tiny"', f'name = "{UNSAFE_NAMES[case]}"'))
    assert_one_error(cli("check", str(p)), "scene.name")


@pytest.mark.parametrize("cmd", ["run", "check"])
@pytest.mark.parametrize("scene", ["scene.toml", "gaussian-hill"])
def test_unsafe_scene_name_from_the_command_line(cmd, scene, tmp_path):
    work = tmp_path / "deep" / "down" / "here"
    work.mkdir(parents=True)
    (work / "scene.toml").write_text(GOOD)
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    quiet = ["--quiet"] if cmd == "run" else []
    res = cli(cmd, scene, "--set", "scene.name=../../../escape", *quiet, cwd=work)
    assert_one_error(res, "scene.name")
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == before


def test_safe_scene_names():
    from pfem2x.scene import SceneError, load_scene

    assert load_scene("gaussian-hill", ["scene.name=Hill_2.v-3"]).name == "Hill_2.v-3"
    assert load_scene("gaussian-hill", ["scene.name=" + "n" * 100]).name == "n" * 100
    with pytest.raises(SceneError, match="scene.name"):
        load_scene("gaussian-hill", ["scene.name=" + "n" * 101])


@pytest.mark.parametrize("cmd", ["check", "run"])
@pytest.mark.parametrize(
    "sets, key",
    [
        (['transport.initial="sin(1,2)"'], "transport.initial"),
        (['transport.initial="hypot(x)"'], "transport.initial"),
        (['transport.initial="min(x)"'], "transport.initial"),
        (['transport.initial="where(x>0,1)"'], "transport.initial"),
        (['transport.initial="9.0**9**9"'], "transport.initial"),
        (['transport.initial="x + 9.0**9**9"'], "transport.initial"),
        (['transport.velocity=["sin()","0"]'], "transport.velocity[0]"),
        (['transport.velocity=["y","x + (-1)**0.5"]'], "transport.velocity[1]"),
    ],
)
def test_expression_mistake_is_bad_input(cmd, sets, key, tmp_path):
    """A wrong argument count or an expression that cannot be evaluated names its key."""
    out = tmp_path / "out"
    args = [a for s in sets for a in ("--set", s)]
    extra = ["--out", str(out), "--quiet"] if cmd == "run" else []
    res = cli(cmd, "gaussian-hill", "--variant", "small", *args, *extra)
    assert_one_error(res, key)
    assert not out.exists()


@pytest.mark.parametrize(
    "sets, key",
    [
        (['transport.velocity=["sqrt(x)","0"]'], "transport.velocity"),
        (['transport.velocity=["y","1e400"]'], "transport.velocity"),
        (["effects.source=true", 'transport.source="x*9.0**9**9"'], "transport.source"),
        (["effects.source=true", 'transport.source="log(x)"'], "transport.source"),
        (['transport.exact="hypot(x)"'], "transport.exact"),
        (['transport.boundary_value="x + 9.0**9**9"'], "transport.boundary_value"),
    ],
)
def test_setup_field_not_finite(sets, key, tmp_path):
    """Expressions evaluated at set-up are bad input when not finite, as the initial field."""
    out = tmp_path / "out"
    args = [a for s in sets for a in ("--set", s)]
    assert_one_error(cli("check", "gaussian-hill", "--variant", "small", *args), key)
    res = cli("run", "gaussian-hill", "--variant", "small", *args, "--out", str(out), "--quiet")
    assert_one_error(res, key)
    assert not out.exists()


@pytest.mark.parametrize("cmd", ["check", "run"])
@pytest.mark.parametrize(
    "scene, sets, key, count",
    [
        ("two-layer-rest", ["method.frame=eulerian", "flow.gravity=[-9.81]"], "flow.gravity", 2),
        ("dam-break", ["flow.gravity=[0,-9.81,0]"], "flow.gravity", 2),
        ("gaussian-hill", ['transport.velocity=["y","1","1"]'], "transport.velocity", 2),
        ("gaussian-hill", ['transport.velocity=["y"]'], "transport.velocity", 2),
        ("manufactured-1d", ['transport.velocity=["1","0"]'], "transport.velocity", 1),
        ("channel", ['flow.inflow_velocity=["1","0","0"]'], "flow.inflow_velocity", 2),
        ("taylor-green", ['flow.initial_velocity=["1","0","0"]'], "flow.initial_velocity", 2),
    ],
)
def test_vector_key_needs_one_component_per_dimension(cmd, scene, sets, key, count, tmp_path):
    out = tmp_path / "out"
    args = [a for s in sets for a in ("--set", s)]
    extra = ["--out", str(out), "--quiet"] if cmd == "run" else []
    res = cli(cmd, scene, "--variant", "small", *args, *extra)
    assert_one_error(res, key, f"expected {count} component")
    assert not out.exists()


@pytest.mark.parametrize("case", ['"nosuch"', '"gausian-hill"', '"manufactured1d"'])
def test_unknown_case_lists_the_known_ones(case):
    res = cli("check", "gaussian-hill", "--variant", "small", "--set", f"scene.case={case}")
    assert_one_error(res, "scene.case", case.strip('"'), "dam-break, gaussian-hill")


def test_known_cases_are_the_registered_ones():
    from pfem2x.cases import _CASES
    from pfem2x.scene_schema import CASES

    # manufactured-1d: the exact-solution error is its measure (no case object)
    assert set(CASES) == set(_CASES) | {"manufactured-1d"}


@pytest.mark.parametrize("frame", ["eulerian", "characteristic"])
def test_expression_failing_during_the_run_ends_it_as_diverged(frame, tmp_path):
    """A source that cannot be evaluated at t = 0.5 ends the run as a divergence does."""
    import json

    out = tmp_path / "out"
    res = cli(
        "run", "gaussian-hill", "--variant", "small", "--set", f"method.frame={frame}",
        "--set", "effects.source=true", "--set", 'transport.source="1/(t-0.5)"',
        "--out", str(out), "--quiet",
    )  # fmt: skip
    assert res.returncode == 3, res.stderr
    assert "Traceback" not in res.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "diverged"
    assert "transport.source" in summary["message"] and "1/(t-0.5)" in summary["message"]


def test_a_tiny_courant_number_names_it_and_the_step_count_in_short():
    res = cli("check", "gaussian-hill", "--variant", "small", "--set", "time.courant=1e-300")
    assert_one_error(res, "time.courant", "e+", "time.max_steps")
    assert len(res.stderr) < 200, res.stderr


def test_bounds_below_the_mesh_generators_precision_are_refused():
    res = cli(
        "check", "gaussian-hill", "--variant", "small", "--set", "mesh.bounds=[[0,0],[1e-300,1]]"
    )
    assert_one_error(res, "mesh.bounds", "extent")


@pytest.mark.parametrize(
    ("scene", "effect", "physics"),
    [("gaussian-hill", "gravity", "flow"), ("two-layer-rest", "diffusion", "transport")],
)
def test_an_effect_of_the_other_physics_is_refused(scene, effect, physics):
    res = cli("check", scene, "--variant", "small", "--set", f"effects.{effect}=true")
    assert_one_error(res, f"effects.{effect}", f"an effect of {physics} scenes")


def test_a_divergence_names_the_expression_that_is_not_finite(tmp_path):
    # numpy gives inf for 1/(x*0 + t - 0.5) at t = 0.5 (no exception): the field follows
    out = tmp_path / "run"
    src = 'transport.source="1/(x*0 + t - 0.5)"'
    res = cli("run", "gaussian-hill", "--variant", "small", "--set", "effects.source=true",
              "--set", src, "--out", str(out), "--quiet")  # fmt: skip
    assert res.returncode == 3, res.stderr
    assert "Traceback" not in res.stderr
    msg = json.loads((out / "summary.json").read_text())["message"]
    assert "transport.source is not finite at" in msg and "t = 0.5" in msg, msg


@pytest.mark.parametrize("frame", ["eulerian", "lagrangian"])
def test_a_flow_divergence_names_the_inflow_velocity(frame, tmp_path):
    """A ``flow.inflow_velocity`` that turns NaN in the run (sqrt of a negative number
    after t = 0.47, no exception) is named in the divergence message, with the count of
    the inflow side's nodes (the small channel's 9)."""
    out = tmp_path / "run"
    inflow = 'flow.inflow_velocity=["4*Um*y*(Hc - y)/Hc**2 + 0*sqrt(0.47 - t + 0*y)", "0"]'
    res = cli("run", "channel", "--variant", "small", "--set", f'method.frame="{frame}"',
              "--set", "time.dt=0.05", "--set", inflow, "--set", "output.png=false",
              "--out", str(out), "--quiet")  # fmt: skip
    assert res.returncode == 3, res.stderr
    assert "Traceback" not in res.stderr
    msg = json.loads((out / "summary.json").read_text())["message"]
    assert "flow.inflow_velocity is not finite at 9 node(s) at t = 0.475" in msg, msg
