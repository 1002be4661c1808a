"""Every parameter of every plugin, fed bad values through ``mi.load_dict`` AND through
XML (``mi.load_string``), must be refused with one message format naming the plugin and
the parameter (mi_plugins.base.params); good values of every accepted form must load.

The table below lists every parameter of the ten plugins with its kind and valid range;
the bad values are generated from the kind (wrong type: a string for a number, 'false'/
'abc'/2 for a boolean, True for an integer; NaN; +-inf; out of range; unknown choice).
Each value goes to XML in the tag of its Python type (bool: <boolean>, int: <integer>,
float: <float>, str: <string>, 3-list/RGB: <rgb>, texture dict: <texture>, reference:
<ref>): XML can express all of them in those tags. What XML's tags themselves cannot
express (<boolean value="abc"/>, <integer value="2.5"/>, <integer value="nan"/>, ...)
never reaches a plugin: Mitsuba's XML parser refuses it first
(test_xml_parser_refuses_what_its_tags_cannot_express).
"""
import gc
import math
import os
import re
from xml.sax.saxutils import quoteattr

import mitsuba as mi
import pytest

from mi_plugins.base import params as params_module
from mi_plugins.base.params import ParameterError, Params

#: these tests load plugins and render nothing: the module collects their objects at its end
#: (``_drop_objects``) instead of after every test (tests/conftest.py, ``_collect_scenes``)
pytestmark = pytest.mark.renders_nothing

NAN, INF = float("nan"), float("inf")
README = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "reference.md")


class Ref:
    """A reference to an object of the scene by id (dict {'type': 'ref'}, XML <ref>)."""

    def __init__(self, ident):
        self.id = ident

    def __repr__(self):
        return "ref:" + self.id


class Param:
    """One parameter: its kind, valid range, bad and good values, and the other
    parameters (``base``) its values need (e.g. ``values`` only with profile='tabulated')."""

    def __init__(self, kind, bad, good, base=None):
        self.kind, self.bad, self.good, self.base = kind, list(bad), list(good), base or {}


WRONG_NUMBER = ["abc", "1", True]                  # a string, a numeric string, a bool


def INT(lo, hi=None, good=None, extra_bad=()):
    bad = WRONG_NUMBER + [2.5, float(lo), NAN, INF, -INF, lo - 1] + ([hi + 1] if hi is not None else [])
    return Param("int", bad + list(extra_bad), good if good is not None else [lo, lo + 1])


def FLOAT(lo, lo_open=False, good=None, extra_bad=()):
    bad = WRONG_NUMBER + [NAN, INF, -INF, float(lo) if lo_open else float(lo) - 0.5]
    return Param("float", bad + list(extra_bad), good if good is not None else [lo + 1, float(lo + 2)])


def BOOL():
    return Param("bool", ["false", "true", "abc", 2, 1, 0, 1.0, NAN], [True, False])


def CHOICE(choices, base=None):
    return Param("choice", ["nonsense", choices[0].upper(), 1, True, NAN], list(choices), base)


def RGB(lo, good, extra_bad=()):
    """float or RGB > lo in every channel"""
    bad = ["abc", True, NAN, INF, -INF, float(lo), [1.0, NAN, 1.0], [1.0, INF, 1.0], [1.0, 1.0, float(lo)],
           {"type": "rgb", "value": [1.0, 1.0, NAN]}]
    return Param("rgb", bad + list(extra_bad), good)


def TEXTURE(good, extra_bad=()):
    """float, RGB or texture >= 0"""
    bad = ["abc", True, NAN, INF, -INF, -0.1, [0.1, NAN, 0.1], [0.1, 0.1, -0.1],
           {"type": "rgb", "value": [0.1, INF, 0.1]}, {"type": "checkerboard", "color0": -1.0},
           {"type": "checkerboard", "color1": NAN}]
    return Param("texture", bad + list(extra_bad), good)


GOOD_TEXTURES = [0.3, 0, [0.1, 0.2, 0.3], {"type": "rgb", "value": [0.3, 0.2, 0.1]},
                 mi.ScalarColor3f(0.2, 0.3, 0.1), {"type": "checkerboard"}]

# ------------------------------------------------------------------------ the table
TABLE = {
    "qmc_lighttrace": {
        "sequence": CHOICE(("sobol", "halton", "faure", "lcg", "independent")),
        "scramble": BOOL(),
        "max_depth": INT(-1, good=[-1, 0, 1, 6]),
        "sequence_depth": INT(0, good=[0, 6]),
        "samples": INT(1, 2 ** 32, good=[1, 1000]),
        "epsilon": FLOAT(0, lo_open=True, good=[1e-3, 1]),
        "batch": INT(1, 2 ** 32),
        "patience": INT(1),
        "max_samples": INT(1, 2 ** 32),
        "gather_samples": INT(1, 1024),
        "share_neighbors": BOOL(),
        "mirror_depth": INT(-1, good=[-1, 0, 3]),
        "patch_size": FLOAT(0, lo_open=True, good=[0.05, 1.0]),
        "subdivide": BOOL(),
        "cluster": BOOL(),
        "dark_levels": INT(0, good=[0, 2]),
        "hide_emitters": BOOL(),
        "display": CHOICE(("gather", "smooth", "patches", "baked")),
        "preview_every": INT(0, good=[0, 4]),
        "emitter_samples": INT(1, 64, good=[1, 3, 8]),
        "crowd_reach": FLOAT(0, good=[0.0, 1.0, 2.5]),
        "steep": FLOAT(0, good=[0.0, 0.5, 2.0]),
        "residual": Param("float", WRONG_NUMBER + [NAN, INF, -INF, -0.5, 1.5], [0.0, 0.25, 1.0], {"display": "smooth"}),
        "refine": BOOL(),
        "refine_threshold": FLOAT(0, lo_open=True, good=[0.05, 1.0]),
        "min_patch_size": FLOAT(0, lo_open=True, good=[0.01, 1.0]),
        "max_patches": INT(1, good=[1, 5000]),
    },
    "stochastic_ray": {
        "iterations": INT(1, hi=1 << 20, good=[1, 32]),
        "max_iterations": INT(32, hi=1 << 20, good=[32, 100]),   # >= iterations (default 32)
        "burn_in": INT(0, good=[0, 31], extra_bad=[32]),          # 32: iterations - 1 = 31 (default 32)
        "max_depth": INT(-1, good=[-1, 0, 5]),
        "hide_emitters": BOOL(),
    },
    "ray_bundle": {
        "iterations": INT(1, hi=1 << 20, good=[1, 64]),
        "burn_in": INT(0, good=[0, 15], extra_bad=[16]),          # 16: iterations - 1 = 15 (default 16)
        "resolution": INT(1),
        "chains": INT(1),
        "bidirectional": BOOL(),
        "first_shot": BOOL(),
        "estimate": CHOICE(("gather", "patch")),
        "direction_sequence": CHOICE(("independent", "halton", "hammersley", "pi"),
                                     base={"stratify_chains": False}),
        "stratify_chains": BOOL(),      # true with direction_sequence != 'independent': test_rules_between_parameters
        "average_diffuse": BOOL(),
        "share_diffuse": BOOL(),
        "gather_nee": BOOL(),
        "patch_size": FLOAT(0, lo_open=True, good=[0.05, 1.0]),
        "subdivide": BOOL(),
        "cluster": BOOL(),
        "dark_levels": INT(0, good=[0, 2]),
        "hide_emitters": BOOL(),
        "max_depth": INT(-1, good=[-1, 0, 5]),
        "delta_surfaces": CHOICE(("refuse", "camera_only")),
        "adaptive": BOOL(),
        "max_iterations": INT(1, hi=1 << 20, good=[1, 200]),
        "point_sources": BOOL(),
        "display": CHOICE(("gather", "smooth", "patches", "baked")),
        "preview_every": INT(0, good=[0, 4]),
        "emitter_samples": INT(1, 64, good=[1, 3, 8]),
        "crowd_reach": FLOAT(0, good=[0.0, 1.0, 2.5]),
        "steep": FLOAT(0, good=[0.0, 0.5, 2.0]),
        "residual": Param("float", WRONG_NUMBER + [NAN, INF, -INF, -0.5, 1.5], [0.0, 0.25, 1.0], {"display": "smooth"}),
        "refine": Param("bool", ["false", "true", "abc", 2, 1, 0, 1.0, NAN], [True, False], {"display": "smooth"}),
        "refine_threshold": FLOAT(0, lo_open=True, good=[0.05, 1.0]),
        "min_patch_size": FLOAT(0, lo_open=True, good=[0.01, 1.0]),
        "max_patches": INT(1, good=[1, 5000]),
    },
    "phong": {
        "diffuse_reflectance": TEXTURE(GOOD_TEXTURES + [0.8], extra_bad=[0.9]),       # 0.9 + ks 0.2 > 1
        "specular_reflectance": TEXTURE(GOOD_TEXTURES + [0.5], extra_bad=[[0.1, 0.6, 0.1]]),  # kd 0.5 + 0.6 > 1
        "exponent": FLOAT(0, good=[0, 10, 2.5]),
    },
    "separable": {
        # the shape's own directional_area emitter has radiance 0.5 (x cos^1): L~ must exceed 0.5
        "target_radiance": RGB(0, good=[2.0, 1, [1.0, 2.0, 3.0], {"type": "rgb", "value": [2.0, 1.0, 0.6]},
                                        mi.ScalarColor3f(0.6, 0.7, 0.8)],
                               extra_bad=[0.5, [2.0, 0.4, 2.0], -1.0]),
        "emission": Param("reference", ["lamp", 1.0, True, [1.0, 1.0, 1.0], Ref("tex"), {"type": "checkerboard"}],
                          [Ref("lamp")]),
        "normalization": CHOICE(("exact", "simulated")),
        "samples": INT(1, good=[1, 16]),
    },
    "directional_area": {
        "radiance": TEXTURE(GOOD_TEXTURES + [5.0]),
        "profile": CHOICE(("cosine_power", "tabulated"), base=lambda v: {"values": "1, 0.5"} if v == "tabulated" else {}),
        "exponent": FLOAT(0, good=[0, 1, 40.5]),
        "values": Param("floats", ["abc", "1", "", "1, abc", "1, nan", "1, inf", "1, -1", "0, 0", "0 0 0", 1.0, 2,
                                   True, [1.0, NAN, 1.0], [1.0, -1.0, 1.0], [0.0, 0.0, 0.0]],
                        ["1, 0.5", "0.2 1.2 1.8 0.4", "0, 1", [1.0, 0.5, 0.0]], base={"profile": "tabulated"}),
    },
    "simulated_area": {
        "target_radiance": RGB(0, good=[1.0, 2, [1.0, 2.0, 3.0], {"type": "rgb", "value": [0.5, 1.0, 1.5]},
                                        mi.ScalarColor3f(1, 1, 1)], extra_bad=[-1.0]),
        "samples": INT(1, good=[1, 4]),
        "estimator": CHOICE(("uniform", "cosine", "bsdf")),
    },
}
_SAMPLER = {
    "sample_count": INT(1, 0xFFFFFFFF, good=[1, 4, 64]),
    "scramble": BOOL(),
    "seed": INT(0, 0xFFFFFFFF, good=[0, 1, 0xFFFFFFFF]),
}
for _name in ("halton", "sobol", "faure"):
    TABLE[_name] = _SAMPLER
for _name in ("padded_sobol", "zsobol", "lattice", "cmj"):      # always randomised: no `scramble`
    TABLE[_name] = {k: v for k, v in _SAMPLER.items() if k != "scramble"}

KIND = {"qmc_lighttrace": "integrator", "stochastic_ray": "integrator", "ray_bundle": "integrator",
        "phong": "bsdf", "separable": "bsdf", "directional_area": "emitter", "simulated_area": "emitter",
        "halton": "sampler", "sobol": "sampler", "faure": "sampler", "padded_sobol": "sampler",
        "zsobol": "sampler", "lattice": "sampler", "cmj": "sampler"}

#: parameters a plugin needs besides the one tested
REQUIRED = {"separable": {"target_radiance": 2.0, "emission": Ref("lamp")},
            "simulated_area": {"target_radiance": 1.0}}

# ------------------------------------------------------------------------ scenes
_scenes = []


def as_dict(value):
    if isinstance(value, Ref):
        return {"type": "ref", "id": value.id}
    if isinstance(value, dict):
        return {k: as_dict(v) for k, v in value.items()}
    return value


def plugin_dict(plugin, values):
    return dict({"type": plugin}, **{k: as_dict(v) for k, v in values.items()})


def scene_dict(plugin, values):
    """The dict that loads ``plugin`` with ``values`` (+ what it needs around it)."""
    d = plugin_dict(plugin, values)
    if plugin == "separable":
        return {"type": "scene", "tex": {"type": "checkerboard", "id": "tex"},
                "r": {"type": "rectangle", "emitter": {"type": "directional_area", "id": "lamp", "radiance": 0.5},
                      "bsdf": d}}
    if KIND[plugin] == "emitter":
        return {"type": "scene", "r": {"type": "rectangle", "emitter": d}}
    return d


def _num(x):
    x = float(x)
    return "nan" if math.isnan(x) else ("inf" if x == INF else ("-inf" if x == -INF else repr(x)))


def xml_value(name, value):
    """XML element of a parameter value, in the tag of its Python type."""
    if isinstance(value, Ref):
        return '<ref name="%s" id="%s"/>' % (name, value.id)
    if isinstance(value, bool):
        return '<boolean name="%s" value="%s"/>' % (name, "true" if value else "false")
    if isinstance(value, int):
        return '<integer name="%s" value="%d"/>' % (name, value)
    if isinstance(value, float):
        return '<float name="%s" value="%s"/>' % (name, _num(value))
    if isinstance(value, str):
        return '<string name="%s" value=%s/>' % (name, quoteattr(value))
    if isinstance(value, dict):
        if value["type"] == "rgb":
            channels = value["value"] if isinstance(value["value"], (list, tuple)) else [value["value"]] * 3
            return xml_value(name, list(channels))
        inner = "".join(xml_value(k, v) for k, v in value.items() if k != "type")
        return '<texture name="%s" type="%s">%s</texture>' % (name, value["type"], inner)
    return '<rgb name="%s" value="%s"/>' % (name, ", ".join(_num(c) for c in value))    # RGB triple


def scene_xml(plugin, values):
    body = "".join(xml_value(k, v) for k, v in values.items())
    kind = KIND[plugin]
    element = '<%s type="%s">%s</%s>' % (kind, plugin, body, kind)
    if plugin == "separable":
        return ('<scene version="3.0.0"><texture type="checkerboard" id="tex"/><shape type="rectangle">'
                '<emitter type="directional_area" id="lamp"><float name="radiance" value="0.5"/></emitter>'
                '%s</shape></scene>' % element)
    if kind == "emitter":
        return '<scene version="3.0.0"><shape type="rectangle">%s</shape></scene>' % element
    return element.replace('<%s ' % kind, '<%s version="3.0.0" ' % kind, 1)


def load(how, plugin, values):
    """The loaded plugin instance (through a scene where it needs one)."""
    if how == "dict":
        obj = mi.load_dict(scene_dict(plugin, values), optimize=False)
    else:
        obj = mi.load_string(scene_xml(plugin, values))
    if plugin == "separable":
        _scenes.append(obj)
        return obj.shapes()[0].bsdf()
    if KIND[plugin] == "emitter":
        _scenes.append(obj)
        return obj.emitters()[0]
    return obj


def values_for(plugin, name, value):
    values = dict(REQUIRED.get(plugin, {}))
    base = TABLE[plugin][name].base
    values.update(base(value) if callable(base) else base)
    values[name] = value
    return values


def error_text(exc):
    """The text of an exception and of everything it wraps (Mitsuba wraps a plugin
    constructor's error in a RuntimeError whose text holds the original one)."""
    parts, seen = [], set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        parts.append("%s: %s" % (type(exc).__name__, exc))
        exc = exc.__cause__ or exc.__context__
    return "\n".join(parts)


def message_pattern(plugin, name):
    """The one message format, naming the plugin and the parameter (alone, or among the
    parameters of a rule between several)."""
    return re.compile(r"%s: (parameter %s=.* is invalid|parameters (\S+=.*, )?%s=.* are invalid together); "
                      r"valid range: \S" % (re.escape(plugin), re.escape(name), re.escape(name)))


def _id(value):
    text = repr(value) if not isinstance(value, mi.ScalarColor3f) else "Color3f"
    return text.replace(" ", "")[:40]


BAD = [(plugin, name, value) for plugin, table in TABLE.items() for name, p in table.items() for value in p.bad]
GOOD = [(plugin, name, value) for plugin, table in TABLE.items() for name, p in table.items() for value in p.good]


@pytest.fixture(scope="module", autouse=True)
def _drop_objects():
    yield
    _scenes.clear()
    gc.collect()   # Dr.Jit traces every live plugin instance: drop the refused ones


@pytest.mark.parametrize("how", ["dict", "xml"])
@pytest.mark.parametrize("plugin, name, value", BAD, ids=["%s-%s-%s" % (p, n, _id(v)) for p, n, v in BAD])
def test_bad_value_is_refused_naming_plugin_and_parameter(plugin, name, value, how):
    values = values_for(plugin, name, value)
    with pytest.raises(Exception) as info:
        load(how, plugin, values)
    text = error_text(info.value)
    assert message_pattern(plugin, name).search(text), text
    assert "ParameterError" in text, text


@pytest.mark.parametrize("how", ["dict", "xml"])
@pytest.mark.parametrize("plugin, name, value", GOOD, ids=["%s-%s-%s" % (p, n, _id(v)) for p, n, v in GOOD])
def test_good_value_loads(plugin, name, value, how):
    obj = load(how, plugin, values_for(plugin, name, value))
    got = read_back(obj, plugin, name)
    if got is None:
        return                                  # textures: loading is the test
    if isinstance(value, Ref):
        assert got == value.id
    elif isinstance(value, bool):
        assert got is value
    elif name == "values" and isinstance(value, str):
        assert got == [float(v) for v in value.replace(",", " ").split()]
    elif isinstance(value, (int, float, str)):
        assert got == ([float(value)] * 3 if isinstance(got, list) else value) and not isinstance(got, bool)
    else:                                       # RGB triple or list of floats
        channels = value["value"] if isinstance(value, dict) else value
        assert got == pytest.approx([float(c) for c in channels], rel=1e-7)   # XML <rgb>: float32


#: how to read a parameter back from the plugin instance (default: the attribute of its name)
READ_BACK = {"target_radiance": lambda o: [float(c) for c in o.target],
             "emission": lambda o: o.emission.id(),
             "values": lambda o: [float(c) for c in o.values],
             "sample_count": lambda o: o.sample_count(),
             "seed": lambda o: o.sampler_seed}


def read_back(obj, plugin, name):
    if name in READ_BACK:
        return READ_BACK[name](obj)
    value = getattr(obj, name, None)
    return value if isinstance(value, (bool, int, float, str)) else None


def test_booleans_given_false_are_false():
    """The measured defect: 'false' strings were true; real False must be False in
    dicts and XML (every boolean of ray_bundle, qmc_lighttrace and the samplers)."""
    for plugin, table in TABLE.items():
        for name, p in table.items():
            if p.kind != "bool" or KIND[plugin] not in ("integrator", "sampler"):
                continue
            for how in ("dict", "xml"):
                assert getattr(load(how, plugin, values_for(plugin, name, False)), name) is False, (plugin, name)


def test_table_covers_every_parameter_the_plugins_read(monkeypatch):
    """Instrument the one reader: loading every good value of the table must read
    exactly the table's parameters, plugin by plugin (every parameter is read)."""
    read = {}
    fetch = Params._fetch

    def recording(self, name, *args, **kwargs):
        read.setdefault(self.plugin, set()).add(name)
        return fetch(self, name, *args, **kwargs)

    monkeypatch.setattr(Params, "_fetch", recording)
    for plugin, name, value in GOOD:
        load("dict", plugin, values_for(plugin, name, value))
    for plugin, table in TABLE.items():
        assert read.get(plugin) == set(table), (plugin, sorted(read.get(plugin, ())), sorted(table))


def _readme_tables():
    """{plugin: [parameter names]} from the plugin reference's tables (docs/reference.md)."""
    tables, current = {}, None
    with open(README, encoding="utf-8") as f:
        for line in f:
            if line.startswith("#"):
                names = re.findall(r"`(\w+)`", line) if re.match(r"###\s+(Integrator|BSDF|Emitter|Samplers?)\b", line) \
                    else []
                current = [n for n in names if n in TABLE] or None
                if current:
                    for n in current:
                        tables[n] = []
                continue
            m = re.match(r"\|\s*`(\w+)`\s*\|", line)
            if current and m:
                for n in current:
                    tables[n].append(m.group(1))
    return tables


def test_table_matches_the_readme_plugin_reference():
    readme = _readme_tables()
    assert set(readme) == set(TABLE)
    for plugin, table in TABLE.items():
        assert sorted(readme[plugin]) == sorted(table), plugin


def test_every_plugin_kind_and_value_kind_is_covered():
    registered = {name for names in mi_plugins_registered().values() for name in names}
    assert registered == set(TABLE)
    assert {p.kind for table in TABLE.values() for p in table.values()} == \
        {"int", "float", "bool", "choice", "rgb", "texture", "reference", "floats"}


def mi_plugins_registered():
    import mi_plugins
    return mi_plugins.registered


def test_coverage_numbers():
    """Every parameter with several bad values of several kinds (see the report printed
    with -s: parameters x bad values x 2 loaders)."""
    n_params = sum(len(table) for table in TABLE.values())
    print("\n%d parameters of %d plugins, %d bad values (x 2: dict and XML), %d good values"
          % (n_params, len(TABLE), len(BAD), len(GOOD)))
    assert all(len(p.bad) >= 5 and p.good for table in TABLE.values() for p in table.values())


@pytest.mark.parametrize("tag, value", [("boolean", "abc"), ("boolean", "2"), ("boolean", "0"),
                                        ("integer", "2.5"), ("integer", "nan"), ("integer", "abc"),
                                        ("integer", "99999999999999999999"), ("float", "abc"),
                                        ("rgb", "1, 2"), ("rgb", "abc")])
def test_xml_parser_refuses_what_its_tags_cannot_express(tag, value):
    """Values XML's own tags cannot carry are refused by Mitsuba's XML parser before a
    plugin is constructed (its message names the value, not the plugin): the table
    therefore gives such values in the tag of their Python type instead (a string in
    <string>, a float in <float>)."""
    xml = '<integrator version="3.0.0" type="ray_bundle"><%s name="chains" value="%s"/></integrator>' % (tag, value)
    with pytest.raises(Exception, match="could not parse"):
        mi.load_string(xml)


def test_unknown_parameter_is_still_reported_by_mitsuba():
    """Params queries only the names it is asked for: a misspelt parameter stays
    unreferenced, and Mitsuba's own check names it (dict and XML)."""
    with pytest.raises(Exception, match='unreferenced property.*\n.*"chain"'):
        mi.load_dict({"type": "ray_bundle", "chain": 4})
    with pytest.raises(Exception, match='unreferenced property.*\n.*"bidirectionnal"'):
        mi.load_string('<integrator version="3.0.0" type="ray_bundle"><boolean name="bidirectionnal" value="false"/>'
                       '</integrator>')


def test_rules_between_parameters_name_both():
    cases = [
        ("stochastic_ray", {"iterations": 4, "burn_in": 4}, ("burn_in", "iterations")),
        ("ray_bundle", {"direction_sequence": "halton", "stratify_chains": True},
         ("stratify_chains", "direction_sequence")),
        ("qmc_lighttrace", {"sequence": "halton", "sequence_depth": 200}, ("sequence_depth", "sequence")),
        ("qmc_lighttrace", {"display": "smooth", "share_neighbors": True}, ("share_neighbors", "display")),
        ("qmc_lighttrace", {"display": "baked", "max_depth": 4}, ("display", "max_depth")),
        ("qmc_lighttrace", {"refine": True, "epsilon": 0.01}, ("refine", "epsilon")),
        ("ray_bundle", {"display": "baked", "max_depth": 4}, ("display", "max_depth")),
        ("ray_bundle", {"refine": True}, ("refine", "display")),
        ("qmc_lighttrace", {"residual": 0.25}, ("residual", "display")),
        ("ray_bundle", {"residual": 0.25}, ("residual", "display")),
        ("phong", {"diffuse_reflectance": 0.7, "specular_reflectance": 0.5},
         ("diffuse_reflectance", "specular_reflectance")),
        ("separable", {"target_radiance": 0.4, "emission": Ref("lamp")}, ("target_radiance", "emission")),
        ("directional_area", {"profile": "tabulated"}, ("values", "profile")),
        ("directional_area", {"profile": "tabulated", "values": "1, 2", "exponent": 2.0}, ("exponent", "profile")),
        ("directional_area", {"values": "1, 2"}, ("values", "profile")),
    ]
    for plugin, values, names in cases:
        for how in ("dict", "xml"):
            with pytest.raises(Exception) as info:
                load(how, plugin, values)
            text = error_text(info.value)
            assert re.search(r"%s: parameters %s=.*, %s=.* are invalid together; valid range: " % (plugin, *names),
                             text), text


def test_required_parameters():
    for plugin, name in (("simulated_area", "target_radiance"), ("separable", "target_radiance")):
        values = dict(REQUIRED[plugin])
        del values[name]
        for how in ("dict", "xml"):
            with pytest.raises(Exception) as info:
                load(how, plugin, values)
            text = error_text(info.value)
            assert "%s: parameter %s=(not given) is invalid; valid range: " % (plugin, name) in text, text
            assert "(required)" in text


def test_message_format():
    props = mi.Properties("ray_bundle")
    props["chains"] = 0
    with pytest.raises(ParameterError) as info:
        Params(props, "ray_bundle").int("chains", 1, lo=1)
    assert str(info.value) == "ray_bundle: parameter chains=0 is invalid; valid range: an integer >= 1"
    assert (info.value.plugin, info.value.names, info.value.values) == ("ray_bundle", ("chains",), (0,))
    assert isinstance(info.value, ValueError)
    props = mi.Properties("x")
    props["flag"] = "false"
    with pytest.raises(ParameterError, match=r"^x: parameter flag='false' is invalid; valid range: a boolean"):
        Params(props, "x").bool("flag", True)
    assert params_module.show([1, NAN, 2]) == "[1.0, nan, 2.0]"


def test_cli_prints_the_parameter_error_in_one_line(tmp_path, capsys):
    from mi_plugins.app import cli
    scene = tmp_path / "bad.xml"
    scene.write_text('<scene version="3.0.0"><integrator type="ray_bundle"><string name="bidirectional" '
                     'value="false"/></integrator></scene>')
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mi-plugins: error: ray_bundle: parameter bidirectional='false' is invalid; valid range: "
                          "a boolean") and "bad.xml" in err and err.count("\n") == 1, err
