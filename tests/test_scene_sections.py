"""The validated scene as typed, frozen sections; cross-key checks made by the scene module."""

import copy
import dataclasses
import tomllib

import pytest

from pfem2x.scene import SECTION_TYPES, SceneError, builtin_scenes, load_scene, validate
from pfem2x.scene_readers import FLOW_COMMON_KEYS, FRAME_KEYS
from pfem2x.scene_schema import SCHEMA
from pfem2x.scene_sections import PhaseSection, Section, thaw

TRANSPORT = {
    "scene": {"name": "tiny"},
    "mesh": {"kind": "rectangle", "bounds": [[0, 0], [1, 1]], "cells": [4, 4]},
    "effects": {"advection": True},
    "transport": {"velocity": ["1", "0"], "initial": "x"},
    "time": {"t_end": 0.1, "dt": 0.05},
}
FLOW = {
    "scene": {"name": "pool", "physics": "flow"},
    "mesh": {"kind": "rectangle", "bounds": [[0, 0], [1, 1]], "cells": [4, 4]},
    "effects": {"gravity": True},
    "flow": {"gravity": [0, -1]},
    "phases": {"water": {"density": 1000}},
    "time": {"t_end": 0.1, "dt": 0.05},
}

#: two phases (the lagrangian frame's open sides need one)
TWO = {
    **FLOW,
    "effects": {"gravity": True, "two_phase": True},
    "phases": {"water": {"density": 1000, "region": "y < 0.5"}, "air": {"density": 1}},
}


def _with(base, **sections):
    raw = copy.deepcopy(base)
    for sec, keys in sections.items():
        raw.setdefault(sec, {}).update(keys)
    return raw


def _scenes():
    for name, path in builtin_scenes().items():
        raw = tomllib.loads(path.read_text())
        for variant in [None, *sorted(raw.get("variants", {}))]:
            yield name, variant


@pytest.mark.parametrize("name, variant", list(_scenes()))
def test_sections_are_typed_and_match_the_mapping_view(name, variant):
    s = load_scene(name, variant=variant)
    for sec, cls in SECTION_TYPES.items():
        section = getattr(s, sec)
        assert type(section) is cls
        assert s[sec] is section
        assert list(section) == list(SCHEMA[sec])
        for k in SCHEMA[sec]:
            value = getattr(section, k)
            assert not isinstance(value, list | dict), (sec, k)  # frozen all the way down
            assert s[sec][k] == thaw(value)
    assert s.time.t_end == s["time"]["t_end"] > 0
    assert s.frame == s.method.frame and s.physics == s.scene.physics
    # the resolved scene reads back to itself (checkpoints hash this text)
    again = validate(tomllib.loads(s.resolved_toml()), s.source, s.base_dir)
    assert again.resolved_toml() == s.resolved_toml()
    assert again.mesh == s.mesh and again.phases == s.phases


def test_dataclass_fields_follow_the_schema():
    for sec, cls in SECTION_TYPES.items():
        names = [f.name for f in dataclasses.fields(cls) if f.name not in cls._derived]
        assert names == list(SCHEMA[sec]), sec
        assert issubclass(cls, Section)


def test_sections_are_read_only():
    s = validate(copy.deepcopy(TRANSPORT))
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.time.t_end = 1.0
    with pytest.raises(TypeError):
        s["time"]["t_end"] = 1.0
    s["mesh"]["cells"].append(7)  # a copy: the scene keeps its cells
    assert s.mesh.cells == (4, 4) and s["mesh"]["cells"] == [4, 4]
    assert s.mesh.num_cells == 32 and "num_cells" not in s["mesh"]
    with pytest.raises(KeyError):
        s["mesh"]["num_cells"]
    with pytest.raises(KeyError):
        s["phases"]  # transport scenes have no phases
    assert dict(s.phases) == {}


def test_validate_leaves_the_raw_dict_alone():
    raw = copy.deepcopy(FLOW)
    validate(raw)
    assert raw == FLOW


def test_phases():
    s = load_scene("rayleigh-taylor")
    assert set(s.phases) == {"heavy", "light"}
    heavy, light = s.phases["heavy"], s.phases["light"]
    assert isinstance(heavy, PhaseSection) and heavy.name == "heavy"
    assert heavy.region is not None and light.region is None
    assert heavy.density > light.density
    # the mapping view of older callers: no "region" key without a region
    assert "region" in s["phases"]["heavy"] and "region" not in s["phases"]["light"]
    assert s["phases"]["heavy"]["density"] == heavy.density
    with pytest.raises(TypeError):
        s.phases["other"] = heavy


def test_resolved_toml_keeps_the_given_key_order():
    raw = copy.deepcopy(FLOW)
    raw["time"] = {"dt": 0.05, "t_end": 0.1}
    raw["effects"]["two_phase"] = True
    raw["phases"] = {"b": {"region": "y < 0.5", "density": 2}, "a": {"density": 1}}
    text = validate(raw).resolved_toml()
    assert "[time]\ndt = 0.05\nt_end = 0.1\nmax_steps" in text
    assert '[phases.b]\nregion = "y < 0.5"\ndensity = 2.0\nviscosity = 0.0\n' in text
    assert text.index("[phases.b]") < text.index("[phases.a]")


def test_frame_table_names_every_switch():
    keys = {f"{sec}.{k}" for sec in ("method", "flow") for k in SCHEMA[sec]}
    listed = set(FLOW_COMMON_KEYS)
    for physics, frames in FRAME_KEYS.items():
        for frame, names in frames.items():
            assert frame in ("eulerian", "lagrangian", "characteristic"), frame
            assert set(names) <= keys, (physics, frame, set(names) - keys)
            assert physics == "flow" or not any(n.startswith("flow.") for n in names)
            listed |= set(names)
    assert keys - listed == {"method.frame"}
    # the table has exactly the frames that validation accepts
    for physics, base in (("transport", TRANSPORT), ("flow", FLOW)):
        for frame in ("eulerian", "lagrangian", "characteristic"):
            raw = _with(base, method={"frame": frame})
            if frame in FRAME_KEYS[physics]:
                validate(raw)
            else:
                with pytest.raises(SceneError, match="method.frame"):
                    validate(raw)


def test_correction_doc_names_no_version():
    doc = SCHEMA["flow"]["correction"].doc
    assert "velocity =" in doc and "momentum =" in doc and "pfem2x <" not in doc


# Checks that solver constructors, the mesh builder, the case hooks and the runner make
# when they meet the scene; validation makes them first.
CROSS = {
    "flow_interval": (
        _with(FLOW, mesh={"kind": "interval", "bounds": [0, 1], "cells": 4}),
        "mesh.kind",
    ),
    "flow_box": (
        _with(FLOW, mesh={"kind": "box", "bounds": [[0, 0, 0], [1, 1, 1]], "cells": [2, 2, 2]}),
        "mesh.kind",
    ),
    "flow_periodic": (_with(FLOW, mesh={"periodic": [True, False]}), "mesh.periodic"),
    "flow_characteristic": (_with(FLOW, method={"frame": "characteristic"}), "method.frame"),
    "flow_inflow_without_velocity": (_with(FLOW, flow={"left": "inflow"}), "flow.inflow_velocity"),
    "lagrangian_two_phase_outflow_side": (
        _with(TWO, method={"frame": "lagrangian"}, flow={"right": "outflow"}),
        "flow.right",
    ),
    "lagrangian_two_phase_inflow_walls": (
        _with(
            TWO,
            method={"frame": "lagrangian"},
            flow={"walls": "inflow", "inflow_velocity": ["1", "0"]},
        ),
        "flow.walls",
    ),
    "flow_initial_velocity_components": (
        _with(FLOW, flow={"initial_velocity": ["0"]}),
        "flow.initial_velocity",
    ),
    "columns_on_an_interval": (
        _with(TRANSPORT, transport={"velocity": ["1"]})
        | {"mesh": {"kind": "interval", "bounds": [0, 1], "cells": 4, "partition": "columns"}},
        "mesh.partition",
    ),
    "grid_on_a_box": (
        _with(TRANSPORT, transport={"velocity": ["1", "0", "0"]})
        | {
            "mesh": {
                "kind": "box",
                "bounds": [[0] * 3, [1] * 3],
                "cells": [2] * 3,
                "partition": [2, 1],
            }
        },
        "mesh.partition",
    ),
    "velocity_components": (_with(TRANSPORT, transport={"velocity": ["1"]}), "transport.velocity"),
    "courant_on_zero_velocity": (
        _with(TRANSPORT, transport={"velocity": ["0", "0.0"]})
        | {"time": {"t_end": 0.1, "courant": 1}},
        "time.courant",
    ),
    "zalesak_without_exact": (_with(TRANSPORT, scene={"case": "zalesak"}), "transport.exact"),
    "zalesak_1d": (
        _with(TRANSPORT, scene={"case": "zalesak"}, transport={"velocity": ["1"], "exact": "x"})
        | {"mesh": {"kind": "interval", "bounds": [0, 1], "cells": 4}},
        "scene.case",
    ),
    "gaussian_hill_params": (
        _with(TRANSPORT, scene={"case": "gaussian-hill"}, params={"x0": 0.5, "y0": 0.5}),
        "params.sigma",
    ),
    "dam_break_params": (_with(FLOW, scene={"case": "dam-break"}), "params.a"),
    "dam_break_transport": (
        _with(TRANSPORT, scene={"case": "dam-break"}, params={"a": 1, "n2": 2, "g": 1}),
        "scene.case",
    ),
    "zalesak_flow": (
        _with(FLOW, scene={"case": "zalesak"}, transport={"exact": "x"}),
        "scene.case",
    ),
    "gaussian_hill_flow": (
        _with(
            FLOW,
            scene={"case": "gaussian-hill"},
            params={"x0": 0.5, "y0": 0.5, "sigma": 0.1, "kappa": 0},
        ),
        "scene.case",
    ),
    "dam_break_one_phase": (
        _with(FLOW, scene={"case": "dam-break"}, params={"a": 1, "n2": 2, "g": 1}),
        "scene.case",
    ),
}


@pytest.mark.parametrize("case", sorted(CROSS))
def test_cross_key_checks(case):
    raw, key = CROSS[case]
    with pytest.raises(SceneError) as info:
        validate(raw)
    msg = str(info.value)
    assert msg.startswith(key + ":"), msg
    assert "\n" not in msg


@pytest.mark.parametrize(
    "raw",
    [
        _with(FLOW, method={"frame": "lagrangian"}, flow={"walls": "noslip", "top": "slip"}),
        _with(FLOW, flow={"left": "inflow", "inflow_velocity": ["1", "0"]}),
        _with(TRANSPORT, mesh={"partition": "columns"}),
        _with(TRANSPORT, mesh={"partition": [2, 1]}),
        _with(TRANSPORT, scene={"case": "zalesak"}, transport={"exact": "x"}),
        _with(
            TRANSPORT,
            scene={"case": "gaussian-hill"},
            params={"x0": 0.5, "y0": 0.5, "sigma": 0.1, "kappa": 0},
        ),
        _with(TRANSPORT, transport={"velocity": ["0", "y"]}) | {"time": {"t_end": 1, "courant": 1}},
        _with(FLOW, scene={"name": "Run_2.v-3"}),
    ],
)
def test_cross_key_checks_accept_good_scenes(raw):
    validate(raw)
