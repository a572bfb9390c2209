"""Scene layers: ``[frames.FRAME]`` tables, then ``[variants.NAME]``, then ``--set``."""

import subprocess
import sys
import tomllib

import pytest

from pfem2x.scene import SceneError, load_scene, validate

BASE = """
[scene]
name = "tiny-flow"
physics = "flow"
[mesh]
kind = "rectangle"
bounds = [[0, 0], [1, 1]]
cells = [4, 4]
[effects]
viscosity = true
[phases.fluid]
density = 1.0
viscosity = 0.01
[flow]
rtol = 1e-8
velocity_scale = 1.0
[time]
t_end = 0.1
courant = 2.0
[method]
frame = "lagrangian"
"""


def write(tmp_path, extra: str):
    p = tmp_path / "scene.toml"
    p.write_text(BASE + extra, encoding="utf-8")
    return p


def test_each_frame_gets_its_own_table():
    lag = load_scene("dam-break")
    eul = load_scene("dam-break", ["method.frame=eulerian"])
    # PFEM-2 with its frame's defaults ("auto": resolved by the flow solver)
    assert (lag.flow.pressure_step, lag.flow.pass_pressure) == ("auto", "auto")
    assert lag.flow.divergence_rtol == "auto" and lag.time.courant == 5.0
    assert (eul.flow.pressure_step, eul.flow.divergence_rtol) == ("auto", "auto")
    assert eul.time.courant == 1.0
    rt = load_scene("rayleigh-taylor")
    assert rt.flow.predictor_particles == 0.5 and rt.flow.rtol == 1e-6
    rt_ls = load_scene("rayleigh-taylor", ["method.frame=eulerian"])
    assert rt_ls.flow.predictor_particles == 1.0 and rt_ls.flow.rtol == 1e-8
    # the variant (no frame keys) keeps each frame's table
    small = load_scene("dam-break", ["method.frame=eulerian"], "small")
    assert small.time.courant == 1.0 and small.mesh.cells == (60, 30)


def test_both_frames_take_the_inflow_velocity_from_a_frame_table(tmp_path):
    # PFEM-2 gives it to the particles that enter, the level set to the inflow side's nodes
    for frame in ("lagrangian", "eulerian"):
        extra = f'[frames.{frame}]\n"flow.inflow_velocity" = ["2*y*(1 - y)", "0"]\n'
        sc = load_scene(str(write(tmp_path, extra)), [f"method.frame={frame}"])
        assert sc.flow.inflow_velocity == ("2*y*(1 - y)", "0")


def test_set_and_variant_win_over_the_frame_table(tmp_path):
    p = write(
        tmp_path,
        """
[frames.lagrangian]
"flow.rtol" = 1e-6
"time.courant" = 4.0
[variants.fine]
"flow.rtol" = 1e-10
""",
    )
    assert load_scene(p).flow.rtol == 1e-6 and load_scene(p).time.courant == 4.0
    assert load_scene(p, variant="fine").flow.rtol == 1e-10
    assert load_scene(p, ["flow.rtol=1e-9"], "fine").flow.rtol == 1e-9
    assert load_scene(p, ["time.courant=8"]).time.courant == 8.0
    sc = load_scene(p, ["time.dt=0.01"])  # replaces the frame table's Courant number
    assert sc.time.dt == 0.01 and sc.time.courant is None
    # another frame: no table
    assert load_scene(p, ["method.frame=eulerian"]).flow.rtol == 1e-8


def test_frame_chosen_by_a_variant_and_a_table_that_sets_dt(tmp_path):
    p = write(
        tmp_path,
        """
[frames.eulerian]
time.dt = 0.02
flow.rtol = 1e-7
[variants.level-set]
"method.frame" = "eulerian"
""",
    )
    sc = load_scene(p, variant="level-set")
    assert sc.method.frame == "eulerian" and sc.flow.rtol == 1e-7
    assert sc.time.dt == 0.02 and sc.time.courant is None
    assert load_scene(p).time.courant == 2.0


def test_a_fixed_step_over_an_adaptive_one_drops_adaptive(tmp_path):
    """``time.dt`` in a later layer replaces the frame table's re-evaluated Courant step."""
    p = write(
        tmp_path,
        """
[frames.lagrangian]
"time.courant" = 3.0
"time.adaptive" = true
"flow.rtol" = 1e-7
[variants.fine]
"time.dt" = 0.01
[variants.fine.frames.lagrangian]
"time.courant" = 1.5
""",
    )
    sc = load_scene(p)
    assert sc.time.courant == 3.0 and sc.time.adaptive and sc.time.dt is None
    for over in (["time.dt=0.05"], ["time.dt=0.05", "method.frame=eulerian"]):
        sc = load_scene(p, over)
        assert sc.time.dt == 0.05 and sc.time.courant is None and not sc.time.adaptive
    assert load_scene(p, ["time.dt=0.05"]).frame_keys == ("flow.rtol = 1e-07",)
    # a layer that gives both: adaptive with a fixed step is refused
    with pytest.raises(SceneError, match="time.adaptive"):
        load_scene(p, ["time.dt=0.05", "time.adaptive=true"])
    # the variant's step, then its frame table's Courant number: adaptive again
    sc = load_scene(p, variant="fine")
    assert sc.time.courant == 1.5 and sc.time.dt is None and sc.time.adaptive is False
    sc = load_scene(p, ["method.frame=eulerian"], "fine")
    assert sc.time.dt == 0.01 and not sc.time.adaptive


def test_a_variant_has_frame_tables_of_its_own(tmp_path):
    p = write(
        tmp_path,
        """
[frames.lagrangian]
"flow.rtol" = 1e-6
"flow.predictor_rtol" = 1e-3
[variants.big]
"time.courant" = 8.0
"flow.rtol" = 1e-7
[variants.big.frames.lagrangian]
"flow.extra_pass" = true
"flow.rtol" = 1e-9
[variants.big.frames.eulerian]
"time.dt" = 0.05
""",
    )
    # the order: the frame table, the variant, the variant's table of the run's frame, --set
    sc = load_scene(p, variant="big")
    assert sc.flow.extra_pass and sc.flow.rtol == 1e-9 and sc.time.courant == 8.0
    assert sc.frame_keys == ("flow.predictor_rtol = 0.001",)
    assert load_scene(p, ["flow.rtol=1e-5"], "big").flow.rtol == 1e-5
    eul = load_scene(p, ["method.frame=eulerian"], "big")
    assert not eul.flow.extra_pass and eul.flow.rtol == 1e-7
    assert eul.time.dt == 0.05 and eul.time.courant is None  # its own table's step wins
    # without the variant none of its tables applies
    plain = load_scene(p)
    assert not plain.flow.extra_pass and plain.flow.rtol == 1e-6
    # the shipped example: each frame runs the rising bubble's large steps with its keys
    lag = load_scene("rising-bubble", ['method.frame="lagrangian"'], "large-steps")
    ls = load_scene("rising-bubble", [], "large-steps")
    assert lag.time.courant == ls.time.courant == 2.0
    assert lag.time.adaptive and ls.time.adaptive  # the flow's Courant number, every step
    assert lag.flow.capillary_damping == ls.flow.capillary_damping == "normal"
    assert (lag.flow.extra_pass, lag.flow.pressure_step) == (True, "increment")
    assert (ls.flow.extra_pass, ls.flow.pressure_step) == (False, "total")
    # PFEM-2's own step (the scene's frame table): Courant 3, 2 at h = 1/40; the level set
    # keeps the fixed steps of the scene and its mesh variants
    for variant, courant, dt in ((None, 3.0, 0.01), ("h40", 2.0, 0.02), ("h160", 3.0, 0.005)):
        lag = load_scene("rising-bubble", ['method.frame="lagrangian"'], variant)
        assert (lag.time.courant, lag.time.dt, lag.time.adaptive) == (courant, None, True)
        assert lag.flow.capillary_increment and lag.flow.extra_pass
        ls = load_scene("rising-bubble", [], variant)
        assert (ls.time.courant, ls.time.dt, ls.time.adaptive) == (None, dt, False)
        assert not ls.flow.capillary_increment
    small = load_scene("rising-bubble", ['method.frame="lagrangian"'], "small")
    assert (small.time.dt, small.time.adaptive) == (0.04, False)


@pytest.mark.parametrize(
    "extra, needles",
    [
        (
            '[variants.v.frames.lagrangain]\n"flow.rtol" = 1e-6\n',
            ["variants.v.frames.lagrangain", "lagrangian"],
        ),
        (
            '[variants.v.frames.lagrangian]\n"flow.rtoll" = 1e-6\n',
            ["variants.v.frames.lagrangian.flow.rtoll"],
        ),
        (
            '[variants.v.frames.lagrangian]\n"method.frame" = "eulerian"\n',
            ["variants.v.frames.lagrangian.method.frame"],
        ),
        (
            '[variants.v.frames.eulerian]\n"flow.pass_pressure" = "consistent"\n',
            ["variants.v.frames.eulerian.flow.pass_pressure", "read by: lagrangian"],
        ),
        ("[variants.v]\nframes = 3\n", ["variants.v.frames"]),
    ],
)
def test_bad_variant_frame_tables(tmp_path, extra, needles):
    p = write(tmp_path, extra)
    with pytest.raises(SceneError) as exc:
        load_scene(p, variant="v")
    for n in needles:
        assert n in str(exc.value), (n, str(exc.value))


def test_nested_variant_tables_set_only_their_leaves(tmp_path):
    p = write(
        tmp_path, "\n[variants.v.flow]\nrtol = 1e-6\n[variants.v.phases.fluid]\ndensity = 2.0\n"
    )
    sc = load_scene(p, variant="v")
    assert sc.flow.rtol == 1e-6 and sc.phases["fluid"].viscosity == 0.01
    assert sc.phases["fluid"].density == 2.0


def test_resolved_scene_has_the_frame_keys_and_no_tables():
    sc = load_scene("dam-break", ["method.frame=eulerian"])
    raw = tomllib.loads(sc.resolved_toml())
    assert "frames" not in raw and "variants" not in raw
    assert raw["flow"]["pressure_step"] == "auto" and raw["time"]["courant"] == 1.0
    again = validate(raw)
    assert again.flow == sc.flow and again.time == sc.time


@pytest.mark.parametrize(
    "extra, needles",
    [
        ('[frames.lagrangain]\n"flow.rtol" = 1e-6\n', ["frames.lagrangain", "lagrangian"]),
        ('[frames.eulerian]\n"flow.rtoll" = 1e-6\n', ["frames.eulerian.flow.rtoll"]),
        ('[frames.eulerian]\n"method.frame" = "lagrangian"\n', ["frames.eulerian.method.frame"]),
        ("[frames]\neulerian = 3\n", ["frames.eulerian"]),
        ("frames = 3\n", ["frames"]),
        ('[frames.lagrangian]\n"flow.rtol" = -1.0\n', ["frames.lagrangian.flow.rtol"]),
        # a value is checked in every frame's table, not only the run's
        (
            '[frames.eulerian]\n"flow.pressure_step" = "totl"\n',
            ["frames.eulerian.flow.pressure_step", "total"],
        ),
        (
            '[frames.eulerian]\n"flow.rtol" = 1e-6\nflow.rtol = 1e-7\n',
            ["frames.eulerian.flow.rtol", "twice"],
        ),
        (
            '[frames.eulerian]\n"phases.fluid.density" = 2.0\n',
            ["frames.eulerian.phases.fluid.density"],
        ),
        (
            '[frames.eulerian]\n"flow.pass_pressure" = "consistent"\n',
            ["frames.eulerian.flow.pass_pressure", "read by: lagrangian"],
        ),
        # a bad key in the second table is named by that table
        (
            '[frames.eulerian]\n"flow.rtol" = 1e-6\n[frames.lagrangian]\n"flow.rtoll" = 1e-6\n',
            ["frames.lagrangian.flow.rtoll"],
        ),
        ('method = "lagrangian"\n', ["method", "table"]),
        ("variants = 3\n", ["variants"]),
    ],
)
def test_bad_frame_tables(tmp_path, extra, needles):
    # the TOML text must come before any table of BASE's to be top-level for `frames = 3`
    p = tmp_path / "scene.toml"
    top = not extra.startswith("[")
    no_method = BASE.replace('[method]\nframe = "lagrangian"\n', "")
    p.write_text(extra + no_method if top else BASE + extra, encoding="utf-8")
    variant = "v" if extra.startswith("variants") else None
    with pytest.raises(SceneError) as exc:
        load_scene(p, variant=variant)
    for n in needles:
        assert n in str(exc.value), (n, str(exc.value))
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "pfem2x",
            "check",
            str(p),
            *(["--variant", variant] if variant else []),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith("error: ") and needles[0] in res.stderr


def test_check_names_the_frame_keys_the_run_takes():
    assert load_scene("rayleigh-taylor").frame_keys == (
        "flow.predictor_particles = 0.5",
        "flow.predictor_substeps = 2",
        "flow.predictor_rtol = 0.0001",
        "flow.predictor_divergence_rtol = 0.2",
        "flow.rtol = 1e-06",
        'flow.divergence_preconditioner = "jacobi"',
    )
    # a --set of one key (or of the step) leaves the others
    sc = load_scene("dam-break", ["method.frame=eulerian"])
    assert sc.frame_keys == ("time.courant = 1.0",)
    assert load_scene("dam-break", ["method.frame=eulerian", "time.dt=0.001"]).frame_keys == ()
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "pfem2x",
            "check",
            "rayleigh-taylor",
            "--set",
            "flow.predictor_particles=1",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith(
        "[frames.lagrangian]: flow.predictor_substeps = 2, flow.predictor_rtol = 0.0001, "
        "flow.predictor_divergence_rtol = 0.2, flow.rtol = 1e-06, "
        'flow.divergence_preconditioner = "jacobi"; '
        'auto: flow.pressure_step = "increment", flow.divergence_rtol = 0.05, '
        'flow.pass_pressure = "increment"'
    )


def test_set_of_a_table_sets_its_leaves_and_frames_are_not_set():
    sc = load_scene("dam-break", ['method={frame="eulerian"}'])
    assert sc.method.frame == "eulerian" and sc.time.courant == 1.0
    assert sc.method.particles_per_cell == 8  # the rest of [method] stays
    sc = load_scene("rayleigh-taylor", ["flow={reinit_every=2}"])
    assert sc.flow.reinit_every == 2 and sc.flow.predictor_particles == 0.5
    for bad in ("frames.lagrangian.flow.rtol=1e-3", "variants.small.mesh.cells=[4,2]"):
        with pytest.raises(SceneError, match="read from the scene file only"):
            load_scene("dam-break", [bad])


@pytest.mark.parametrize(
    "extra, needles",
    [
        ('[variants.small]\n"mesh.nosuch" = 1\n', ["variants.small.mesh.nosuch", "unknown key"]),
        ('[variants.small]\n"flow.rtoll" = 1e-6\n', ["variants.small.flow.rtoll", "flow.rtol"]),
        ('[variants.small]\n"time.dt" = -1\n', ["variants.small.time.dt"]),
        ('[variants.small]\n"variants.x" = 3\n', ["variants.small.variants.x"]),
        ('[variants.small]\n"frames.eulerian" = 3\n', ["variants.small.frames.eulerian"]),
        ('[variants.small]\n"mesch.cells" = [2, 2]\n', ["variants.small.mesch.cells"]),
        ('[variants.small]\n"phases.fluid.densty" = 2.0\n', ["variants.small.phases.fluid"]),
        ("[variants]\nsmall = 3\n", ["variants.small"]),
        (
            '[variants.small.frames.lagrangian]\n"flow.rtoll" = 1e-6\n',
            ["variants.small.frames.lagrangian.flow.rtoll"],
        ),
    ],
)
def test_check_checks_every_variant(tmp_path, extra, needles):
    """A bad key of any variant is refused by check, with or without --variant."""
    p = write(tmp_path, "\n" + extra)
    with pytest.raises(SceneError) as exc:
        load_scene(p)
    for n in needles:
        assert n in str(exc.value), (n, str(exc.value))
    res = subprocess.run(
        [sys.executable, "-m", "pfem2x", "check", str(p)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith("error: ") and needles[0] in res.stderr
    assert "Traceback" not in res.stderr


def test_shipped_scenes_and_their_variants_pass_check():
    from pfem2x.scene import builtin_scenes

    for name, path in builtin_scenes().items():
        load_scene(name)
        for variant in tomllib.loads(path.read_text()).get("variants", {}):
            load_scene(name, variant=variant)
