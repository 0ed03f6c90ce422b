"""Property-based tests (Hypothesis) of everything a user types: configs, scene specs and CLI arguments.

The property: whatever comes in, `nlosbench` ends with exit 0 (it ran), 2 (bad input: one line
`nlosbench: error: ...` naming the key path or the file) or 1 (environment) — never exit 3 (an internal
error), never a traceback — and a refused run leaves `--out` absent. Three ways in:
(a) configs: each shipped config (configs/, tests/configs/) with keys, values, types and nesting mutated,
    through the config validation `nlosbench run` does first (`config.load`), the whole check before
    anything is written (`runner.prepare`, on an analytic scene) and, for a few, `nlosbench run --smoke`;
(b) scene specs: a spec's keys and `params` entries mutated (`scenes.read_spec`, `scenes.load_spec`), and
    specs that are lists, strings, XML files, folders, missing, unreadable or name invalid XML;
(c) CLI arguments: subcommands, flags and `--set` overrides of every kind.

Profiles: `make test` runs the "make-test" profile (derandomized, no example database, the whole file in
under 20 s); HYPOTHESIS_PROFILE=nightly runs 50× the examples with random seeds (minutes). Every failure
found is kept below as a named regression test (an explicit example).
"""
from __future__ import annotations

import contextlib
import copy
import io
import math
import os
import shutil
import tempfile
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from nlosbench import scenes
from nlosbench.cli import BAD_INPUT, ENVIRONMENT, INTERNAL, OK, main
from nlosbench.experiment import config, runner
from nlosbench.schema import ConfigError

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml")) + sorted((ROOT / "tests" / "configs").glob("*.yaml"))
SPEC = ROOT / "scenes" / "cornell_ball.yaml"

settings.register_profile("make-test", derandomize=True, database=None, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
settings.register_profile("nightly", max_examples=2000, deadline=None, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "make-test"))
NIGHTLY = os.environ.get("HYPOTHESIS_PROFILE") == "nightly"


def examples(n: int) -> settings:
    """n examples under `make test`, 50 n in the nightly profile."""
    return settings(max_examples=n * 50 if NIGHTLY else n)


#: a seconds-long config on an analytic scene (no Mitsuba load, renders in microseconds)
TINY = {"name": "fuzz", "seed": 1, "scene": {"name": "edge1d", "options": {"render_noise": 0.05}},
        "noise": [{"model": "awgn", "sigma": 0.05}], "executor": {"type": "serial"},
        "studies": [{"type": "bounds", "grid": {"start": 0.3, "stop": 0.7, "num": 5}, "spp": 4},
                    {"type": "trials", "theta": [0.5], "n": 2, "n_eff": 4, "truth_replicates": 2, "hcr_grid": 5,
                     "bound_spp": 4, "replicates": 2, "bootstrap": 5,
                     "estimators": [{"name": "grid-search", "options": {"num": 5, "spp": 1, "refine_evals": 3}}]}]}

# -- values a user might type (or a tool might write) where another was expected --------------------------------
SPECIAL = [None, "", " ", "64", "0.5", "1e3", "nan", "inf", "-inf", "true", "null", math.nan, math.inf, -math.inf,
           1e308, -1e308, 1e-308, 5e-324, 0, -1, 1, 2**31, 2**63, 2**70, -2**70, 0.0, -0.0, True, False, [], {},
           [1, 2], {"a": 1}, [[0.5]], [None], {"start": 0, "stop": 1, "num": 3}, "θ→∞ ✓", "\u00e9\u0301",
           "../../escape", "/tmp/elsewhere", "a/b", "..", ".", "x" * 300, "\t\n", "~/x", "C:\\x", "studies",
           "blob2d", "awgn", "poisson", "common", "all", "auto", "local", "dask"]
LEAF = st.one_of(st.sampled_from(SPECIAL), st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
                 st.text(max_size=12), st.booleans())
VALUE = st.recursive(LEAF, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                   st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                     max_leaves=6)
OPS = ("set", "delete", "wrap_list", "as_map", "unknown_key", "typo", "stringify", "scale", "duplicate")


def nodes(obj, path=()) -> list[tuple]:
    """Every path (a tuple of keys and indices) into a nested dict/list structure, the root included."""
    out = [path]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += nodes(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += nodes(v, path + (i,))
    return out


def mutate(raw, path: tuple, op: str, value):
    """A copy of `raw` with one mutation at `path` (see OPS); the root may be replaced."""
    raw = copy.deepcopy(raw)
    if not path:
        return value if op == "set" else [raw] if op == "wrap_list" else raw
    parent = raw
    for k in path[:-1]:
        parent = parent[k]
    key, old = path[-1], parent[path[-1]]
    if op == "set":
        new = value
    elif op == "delete":
        if isinstance(parent, dict):
            del parent[key]
        else:
            parent.pop(key)
        return raw
    elif op == "wrap_list":
        new = [old]
    elif op == "as_map":
        new = dict(enumerate(old)) if isinstance(old, list) else {"value": old}
    elif op == "unknown_key":
        new = {**old, "bogus_key": value} if isinstance(old, dict) else old
    elif op == "typo":
        if isinstance(parent, dict) and isinstance(key, str):
            parent[key[:-1] + "_" if key else "_"] = parent.pop(key)
            return raw
        new = old
    elif op == "stringify":
        new = str(old)
    elif op == "scale":
        new = old * 10**6 if isinstance(old, (int, float)) and not isinstance(old, bool) else old
    else:  # duplicate
        new = [old, old] if not isinstance(old, list) else old + old
    parent[key] = new
    return raw


@st.composite
def mutated(draw, base):
    """`base` with 1–3 mutations at random places."""
    raw = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(nodes(raw)))
        raw = mutate(raw, path, draw(st.sampled_from(OPS)), draw(VALUE))
    return raw


def one_line(e: ConfigError) -> None:
    """A ConfigError is one line that names a key path or a file."""
    text = str(e)
    assert "\n" not in text and text.split(":")[0].strip(), text


def cli(*args) -> tuple[int, str, str]:
    """`nlosbench ARGS` in this process: (exit code, stdout, stderr); argparse's own exit included."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([str(a) for a in args])
        except SystemExit as e:  # argparse: --help, --version, a usage error
            rc = e.code if isinstance(e.code, int) else 2
    return rc, out.getvalue(), err.getvalue()


def check_outcome(rc: int, err: str, out_dir: Path | None = None) -> None:
    """The CLI property: exit 0, 1 or 2; an error is one `nlosbench: error:` line (argparse adds its usage
    line first), never a traceback; a refused run wrote nothing to --out."""
    assert rc in (OK, ENVIRONMENT, BAD_INPUT), (rc, err)
    assert "Traceback" not in err, err
    if rc != OK:
        errors = [line for line in err.splitlines() if line.startswith("nlosbench: error: ")]
        assert len(errors) == 1 and errors[0] == err.strip().splitlines()[-1], err
    if rc == BAD_INPUT and out_dir is not None:
        assert not out_dir.exists(), f"refused, yet {out_dir} was written: {err}"


def load_raw(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


# -- (a) configs ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_mutated_configs_validate_or_name_the_key(path, tmp_path_factory):
    """Any mutation of a shipped config: `config.load` returns a config or raises one ConfigError line."""
    base = load_raw(path)
    folder = tmp_path_factory.mktemp("cfg")
    for f in ("cornell_ball.yaml", "cornell_ball.xml"):  # a relative spec beside the config
        shutil.copy(ROOT / "scenes" / f, folder / f)

    @examples(8)
    @given(raw=mutated(base))
    def prop(raw):
        target = folder / "c.yaml"
        target.write_text(yaml.safe_dump(raw, allow_unicode=True))
        try:
            config.load(target)
        except ConfigError as e:
            one_line(e)

    prop()


@examples(60)
@given(raw=mutated(TINY))
def test_mutated_configs_pass_or_are_refused_before_anything_is_written(raw):
    """The whole check `nlosbench run` makes before writing (`runner.prepare`: config, scene, each study's
    plan and cost, the run folder) on an analytic scene: a plan, or one ConfigError line; nothing written."""
    with tempfile.TemporaryDirectory() as d:
        cfg, out = Path(d) / "c.yaml", Path(d) / "run"
        cfg.write_text(yaml.safe_dump(raw, allow_unicode=True))
        try:
            run = runner.prepare(cfg, out=out, quiet=True, yes=False)
        except ConfigError as e:
            one_line(e)
        else:
            run.ctx.close()
        assert not out.exists()


@examples(4)
@given(raw=mutated(TINY))
def test_mutated_configs_run_in_smoke_mode_or_are_refused(raw):
    """`nlosbench run --smoke` in this process on a mutated tiny config: exit 0, or 2 with --out absent. The
    executor stays serial (spawning worker pools per example would take minutes; the executor block is fuzzed
    through the config tests above)."""
    if isinstance(raw, dict):
        raw = {**raw, "executor": {"type": "serial"}}
    with tempfile.TemporaryDirectory() as d:
        cfg, out = Path(d) / "c.yaml", Path(d) / "run"
        cfg.write_text(yaml.safe_dump(raw, allow_unicode=True))
        rc, _, err = cli("run", cfg, "--smoke", "--quiet", "--out", out)
        check_outcome(rc, err, out)


# -- (b) scene specs -----------------------------------------------------------------------------------------------
@examples(80)
@given(raw=st.one_of(mutated(load_raw(SPEC)), VALUE))
def test_mutated_specs_read_or_name_the_file(raw):
    """A spec mapping mutated (or any YAML value in its place): `read_spec` returns it or one line naming it."""
    with tempfile.TemporaryDirectory() as d:
        spec = Path(d) / "s.yaml"
        spec.write_text(yaml.safe_dump(raw, allow_unicode=True))
        try:
            scenes.read_spec(spec)
        except ConfigError as e:
            one_line(e)
            assert str(spec) in str(e)


@examples(12)
@given(raw=mutated(load_raw(SPEC)))
def test_mutated_specs_load_or_name_the_file(raw):
    """The same spec loaded into Mitsuba (bindings, defines, the scene file): a model, or one line naming it."""
    with tempfile.TemporaryDirectory() as d:
        shutil.copy(ROOT / "scenes" / "cornell_ball.xml", Path(d) / "cornell_ball.xml")
        spec = Path(d) / "s.yaml"
        spec.write_text(yaml.safe_dump(raw, allow_unicode=True))
        try:
            model = scenes.load_spec(spec, defines={"res": 8})
        except ConfigError as e:
            one_line(e)
            assert str(spec) in str(e) or "params" in str(e) or "defines" in str(e), str(e)
        else:  # a model: the parameters the spec names, in its order, each with a non-empty range
            params = raw.get("params") if isinstance(raw, dict) else None
            ok = isinstance(params, list) and all(isinstance(p, dict) and "name" in p for p in params)
            names = [p["name"] for p in params] if ok else None
            assert names is None or list(model.params.names) == [str(n) for n in names]
            assert all(lo < hi for lo, hi in zip(model.params.lower, model.params.upper, strict=True))


BAD_SPECS = {  # name → (file content or None for a folder, where the spec is named)
    "list.yaml": "- file: cornell_ball.xml\n- params: []\n",
    "string.yaml": "cornell_ball.xml\n",
    "number.yaml": "3\n",
    "empty.yaml": "",
    "scene.xml": (ROOT / "scenes" / "cornell_ball.xml").read_text(),
    "xml_inside.yaml": (ROOT / "scenes" / "cornell_ball.xml").read_text(),
    "folder.yaml": None,
    "bad_yaml.yaml": "file: [unclosed\n",
    "binary.yaml": b"\xff\xfe\x00\x01",
    "defines_list.yaml": "file: cornell_ball.xml\ndefines: [res, 8]\nparams: [{name: r, kind: radius, object: ball, "
                         "lower: 0.1, upper: 0.4, default: 0.3}]\n",
    "define_type.yaml": "file: cornell_ball.xml\ndefines: {res: [8]}\nparams: [{name: r, kind: radius, object: ball, "
                        "lower: 0.1, upper: 0.4, default: 0.3}]\n",
    "invalid_xml.yaml": "file: broken.xml\nparams: [{name: r, kind: radius, object: ball, lower: 0.1, upper: 0.4, "
                        "default: 0.3}]\n",
    "params_string.yaml": "file: cornell_ball.xml\nparams: ball_x\n",
    "file_number.yaml": "file: 3\nparams: [{name: r, kind: radius, object: ball, lower: 0.1, upper: 0.4, "
                        "default: 0.3}]\n",
}


@pytest.fixture(scope="module")
def bad_specs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("specs")
    shutil.copy(ROOT / "scenes" / "cornell_ball.xml", d / "cornell_ball.xml")
    (d / "broken.xml").write_text('<scene version="3.0.0">\n  <shape type="sphere"\n</scene>\n')
    for name, text in BAD_SPECS.items():
        if text is None:
            (d / name).mkdir()
        elif isinstance(text, bytes):
            (d / name).write_bytes(text)
        else:
            (d / name).write_text(text)
    return d


@pytest.mark.parametrize("name", [*BAD_SPECS, "missing.yaml"])
def test_a_bad_spec_is_one_line_naming_it_from_the_config_and_from_check_scene(bad_specs, tmp_path, name):
    """Every bad spec, named by a config's `scene.name` and by `nlosbench check-scene`: exit 2, one line naming
    the file (and the key `scene` from a config), nothing written."""
    spec = bad_specs / name
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({**TINY, "scene": {"name": str(spec)}}))
    for args, out in ((("run", cfg), tmp_path / "run"), (("check-scene", spec, "--spp", "1"), tmp_path / "chk")):
        rc, _, err = cli(*args, "--out", out)
        check_outcome(rc, err, out)
        assert rc == BAD_INPUT and str(spec) in err, err
        assert args[0] != "run" or err.startswith("nlosbench: error: scene"), err


@pytest.mark.parametrize("name", ["scene.xml", "list.yaml", "string.yaml", "xml_inside.yaml", "folder.yaml"])
def test_an_xml_file_list_or_string_where_a_spec_belongs_says_how_to_write_one(bad_specs, tmp_path, name):
    """Task: an XML file (or a YAML list or string) given as a spec: one line saying how to write the spec,
    naming `file:`, `params:`, `nlosbench check-scene` and examples/own_scene.py; nothing written."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({**TINY, "scene": {"name": str(bad_specs / name)}}))
    for args in (("check-scene", bad_specs / name), ("render", bad_specs / name), ("run", cfg)):
        rc, _, err = cli(*args, "--out", tmp_path / "out")
        assert rc == BAD_INPUT and len(err.strip().splitlines()) == 1, err
        for words in ("`file:`", "`params:`", "nlosbench check-scene", "examples/own_scene.py"):
            assert words in err, err
        assert not (tmp_path / "out").exists()


def test_an_unreadable_spec_is_an_environment_error(bad_specs, tmp_path, monkeypatch):
    """A spec the process may not read (simulated: tests may run as root): exit 1 naming the file."""
    spec = bad_specs / "list.yaml"
    real = Path.read_text

    def denied(self, *a, **k):
        if self == spec:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self, *a, **k)

    monkeypatch.setattr(Path, "read_text", denied)
    rc, _, err = cli("check-scene", spec, "--out", tmp_path / "out")
    check_outcome(rc, err, tmp_path / "out")
    assert rc == ENVIRONMENT and str(spec) in err and "EACCES" in err, err


# -- (c) CLI arguments ---------------------------------------------------------------------------------------------
KEYS = sorted({".".join(str(k) for k in p) for p in nodes(TINY) if p}) + ["studies.7.spp", "nosuch", "a..b", ".x",
                                                                          "studies.-1.spp", "studies.x.spp", ""]
WORD = st.one_of(st.sampled_from(["run", "render", "check-scene", "list", "report", "keys", "scenes", "studies",
                                  "trials", "bounds", "blob2d", "edge1d", "--quiet", "--resume",
                                  "--smoke", "--spp", "--seed", "--theta", "--define", "--set", "--bogus", "-x", "--",
                                  "-", "0", "-1", "1e400", "nan", "res=8", "=", "--out"]),
                 st.text(max_size=8))


@st.composite
def overrides(draw) -> list[str]:
    items = []
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.one_of(st.sampled_from(KEYS), st.text(max_size=10)))
        odd = ["[1, 2", "{a: 1}", "!!python/object:os.system", "*alias", "&a 1", "'x", "1\n2"]
        value = draw(st.one_of(st.sampled_from([str(v) for v in SPECIAL] + odd), st.text(max_size=10)))
        items += ["--set", draw(st.sampled_from([f"{key}={value}", key, f"{key}=", f"={value}"]))]
    return items


@examples(40)
@given(sets=overrides())
def test_set_overrides_of_every_kind_pass_or_are_refused(sets):
    """`nlosbench run TINY --set ...` (checked, not executed: `Run.execute` is replaced by a stub that writes
    nothing): exit 0 or 2 with one line; nothing written."""
    with tempfile.TemporaryDirectory() as d:
        cfg, out = Path(d) / "c.yaml", Path(d) / "run"
        cfg.write_text(yaml.safe_dump(TINY))
        execute = runner.Run.execute
        runner.Run.execute = lambda self: (self.ctx.close(), self.dir)[1]
        try:
            rc, _, err = cli("run", cfg, "--out", out, "--quiet", *sets)
        finally:
            runner.Run.execute = execute
        check_outcome(rc, err, out)
        assert not out.exists()


@examples(50)
@given(argv=st.lists(WORD, min_size=0, max_size=6))
def test_any_command_line_exits_0_1_or_2_with_one_error_line(argv):
    """Random words after `nlosbench` (unknown subcommands and flags included; `run` and `bench`, which would
    run long, only with a config that does not exist): exit 0, 1 or 2, no traceback, nothing written."""
    assume(not argv or argv[0] != "bench" or any(a.startswith("-") and a != "--reduced" for a in argv))
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "out"
        if argv and argv[0] in ("run", "render", "check-scene"):
            argv = argv + ["--out", str(out)]
        if argv and argv[0] == "run":
            argv = ["run", str(Path(d) / "none.yaml"), *argv[1:]]
        if argv and argv[0] == "bench":
            argv = ["bench", "--bogus"]
        rc, _, err = cli(*argv)
        check_outcome(rc, err)


# -- internal errors (exit 3) --------------------------------------------------------------------------------------
def test_an_internal_error_mid_run_is_exit_3_with_the_traceback_in_the_run_folder(tmp_path, monkeypatch):
    """A ValueError raised by a study after the config was checked is not bad input: exit 3, one line saying it
    is an internal error, where the traceback is (RUN/error.log) and how to resume."""
    from nlosbench.studies import bounds

    def broken(ctx, cfg):
        raise ValueError("a bug deep inside")

    monkeypatch.setattr(bounds, "run", broken)
    cfg, out = tmp_path / "c.yaml", tmp_path / "run"
    cfg.write_text(yaml.safe_dump(TINY))
    rc, _, err = cli("run", cfg, "--out", out, "--quiet")
    assert rc == INTERNAL and len(err.strip().splitlines()) == 1, err
    assert "internal error" in err and "ValueError" in err and "a bug deep inside" in err, err
    assert f"{out / 'error.log'}" in err and "resume with: nlosbench run" in err and "--resume" in err, err
    assert "a bug deep inside" in (out / "error.log").read_text()
    assert "Traceback" in (out / "error.log").read_text()


def test_a_ctrl_c_that_dr_jit_re_raised_as_its_own_error_is_an_interrupt(tmp_path, monkeypatch):
    """A Ctrl-C inside a Dr.Jit call (a frozen function, a symbolic loop) comes back as a RuntimeError caused by the
    KeyboardInterrupt (here a real `drjit.freeze` whose body raises it, called by a study): exit 130, one line
    "interrupted" with how to resume, not "internal error (a bug ...)"."""
    import drjit as dr

    from nlosbench.studies import bounds

    def body(x):
        raise KeyboardInterrupt

    def interrupted(ctx, cfg):
        from drjit.llvm.ad import Float

        dr.freeze(body)(Float(1.0))

    monkeypatch.setattr(bounds, "run", interrupted)
    cfg, out = tmp_path / "c.yaml", tmp_path / "run"
    cfg.write_text(yaml.safe_dump(TINY))
    rc, _, err = cli("run", cfg, "--out", out, "--quiet")
    assert rc == 130 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("nlosbench: error: interrupted") and "--resume" in err and "internal" not in err, err


def test_an_internal_error_before_the_run_folder_exists_goes_to_a_temporary_file(tmp_path, monkeypatch):
    """An internal error while checking (no run folder yet): exit 3, the traceback in a temporary file named
    on the line, --out not created."""
    from nlosbench.studies import bounds

    def broken(ctx, cfg):
        raise KeyError("planned badly")

    monkeypatch.setattr(bounds, "plan", broken)
    cfg, out = tmp_path / "c.yaml", tmp_path / "run"
    cfg.write_text(yaml.safe_dump(TINY))
    rc, _, err = cli("run", cfg, "--out", out, "--quiet")
    assert rc == INTERNAL and not out.exists(), err
    log = Path(err.split("full traceback in ")[1].split(";")[0].strip())
    try:
        assert log.is_file() and "planned badly" in log.read_text() and "resume" not in err
    finally:
        log.unlink(missing_ok=True)


# -- regressions the fuzzing found (each an explicit example) ------------------------------------------------------
@pytest.mark.parametrize("text", ["- name: a\n- studies: []\n", "just a string\n", "3\n"],
                         ids=["list", "string", "int"])
def test_regression_a_config_that_is_not_a_mapping(tmp_path, text):
    """Found by the fuzzing: a config file holding a YAML list raised AttributeError (exit 3 now, a traceback
    then); it is bad input naming the file."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    rc, _, err = cli("run", cfg, "--out", tmp_path / "run")
    check_outcome(rc, err, tmp_path / "run")
    assert rc == BAD_INPUT and str(cfg) in err and "not a mapping" in err, err


@pytest.mark.parametrize("kind", [None, ["fidelity"], {"a": 1}, 3], ids=["null", "list", "map", "int"])
def test_regression_a_study_type_that_is_not_a_string(kind):
    """Found by the fuzzing: `type: [fidelity]` raised TypeError (unhashable list), `type: null` a TypeError
    inside difflib; both are one ConfigError line naming studies[0].type."""
    with pytest.raises(ConfigError, match=r"^studies\[0\]\.type: expected a study type"):
        config.resolve({**TINY, "studies": [{**TINY["studies"][0], "type": kind}]})


@pytest.mark.parametrize("argv", [["--quiet", "run"], ["run"], ["frob"], ["list", "nosuch"], ["render"]])
def test_regression_usage_errors_are_one_line(argv):
    """Found by the fuzzing: argparse's usage errors were two or more lines (`usage: ...` then `nlosbench run:
    error: ...`); now one line `nlosbench: error: ... (nlosbench run --help)`, exit 2."""
    rc, _, err = cli(*argv)
    assert rc == BAD_INPUT and len(err.strip().splitlines()) == 1 and err.startswith("nlosbench: error: "), err
    assert "--help)" in err


@pytest.mark.parametrize("argv", [["list", "keys", "bound"], ["bench", "nosuch"]])
def test_regression_an_unknown_study_or_benchmark_name_is_bad_input(argv):
    """Found while reclassifying errors: `list keys bound` (a KeyError) and `bench nosuch` (an ImportError, a
    traceback before) are bad input: exit 2, one line naming what is available."""
    rc, _, err = cli(*argv)
    assert rc == BAD_INPUT and len(err.strip().splitlines()) == 1 and "available" in err, err


@pytest.mark.parametrize("binding", ["axis: [.inf, 0, 0]", "axis: [.nan, 1, 0]"], ids=["inf", "nan"])
def test_regression_a_translate_axis_that_is_not_finite(tmp_path, binding):
    """Found by the nightly fuzzing: `axis: [.inf, 0, 0]` passed (its norm is > 0) and became a NaN axis (a
    RuntimeWarning, then NaN renders); it is one line naming the spec and the parameter."""
    shutil.copy(ROOT / "scenes" / "cornell_ball.xml", tmp_path / "cornell_ball.xml")
    spec = tmp_path / "s.yaml"
    spec.write_text("file: cornell_ball.xml\nparams:\n  - {name: x, kind: translate, object: ball, " + binding
                    + ", lower: -0.1, upper: 0.1, default: 0}\n")
    with pytest.raises(ConfigError, match=r"s\.yaml: parameter 'x': translate needs a finite, non-zero 3-vector"):
        scenes.load_spec(spec, defines={"res": 8})


@pytest.mark.parametrize("executor, key", [({"workers": 0}, "executor.workers"), ({"workers": -3}, "executor.workers"),
                                           ({"workers": 2**40}, "executor.workers"),
                                           ({"connect_timeout": math.inf}, "executor.connect_timeout"),
                                           ({"connect_timeout": 0}, "executor.connect_timeout")])
def test_regression_executor_settings_are_checked_with_the_config(tmp_path, executor, key):
    """Found while looking into a stalled nightly fuzz run (mutated `executor` blocks): `workers: 0` passed the
    config and failed only when the run started its executor (a ValueError after the run folder was made, so
    an internal error), and an infinite connect_timeout would wait for ever; both are refused with the config,
    nothing written."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({**TINY, "executor": {"type": "local", **executor}}))
    rc, _, err = cli("run", cfg, "--out", tmp_path / "run")
    check_outcome(rc, err, tmp_path / "run")
    assert rc == BAD_INPUT and f"nlosbench: error: {key}: expected" in err, err
