"""Model and parameter text is bounded before it is parsed (springtrack.toml_bounds):
the reproductions of hostile TOML (a deep dotted key, hostile types, unsafe tracker ids)
refused with a clear error, in bounded time and memory, through the Python API, the CLI
and the firmware's link (validated off the link's thread while other sessions are
answered); and a fuzz target over model text."""
from __future__ import annotations

import subprocess
import sys
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hostctl import Device, Nacked, Role
from springtrack import model as _model
from springtrack import params as _params
from springtrack import toml_bounds
from springtrack.wire import Nack

from support.link import TcpServed
from support.engine import SimEngine
from support import REPO

HERE = REPO / "tests" / "support"
GOOD = _model.grid3x3().to_toml()


def deep_key(nbytes: int) -> str:
    """``a.a.a...a = 1`` of about ``nbytes``: tomllib's cost is quadratic in its depth."""
    return ".".join(["a"] * (nbytes // 2)) + " = 1\n"


def test_a_deep_dotted_key_is_refused_before_parsing_by_every_api(tmp_path):
    text = deep_key(60_000)
    t0 = time.perf_counter()
    with pytest.raises(_model.ModelError, match="dotted key .* too many parts .*at most 8"):
        _model.loads(text, "m.toml")
    p = tmp_path / "p.toml"
    p.write_text("[params]\n" + text)
    with pytest.raises(_params.ParamError, match="dotted key"):
        _params.load(p)
    with pytest.raises(_params.ParamError, match="dotted key"):
        _params.resolve(_model.grid3x3(), p)
    # each refusal scans the text once: well under the seconds tomllib would take
    assert time.perf_counter() - t0 < 5


@pytest.mark.parametrize("text,match", [
    ("x = " + "[" * 9 + "]" * 9, "nested too deeply"),
    ("x = {a = {b = {c = {d = {e = {f = {g = {h = {i = 1}}}}}}}}}", "nested too deeply"),
    ("[" + ".".join("t" * 9) + "]\n", "table header of too many parts"),
    ("x = [" + "1," * (toml_bounds.MAX_ITEMS + 1) + "]", "too many keys"),
    ("x = '" + "y" * (toml_bounds.MAX_TEXT_BYTES) + "'", "limited to 262144 bytes"),
    ("x = " + "9" * 5000, "not valid TOML"),
    ("#\n" * toml_bounds.MAX_LINES, "limited to 8192 lines"),
    ("x = " + "1." * (toml_bounds.MAX_MARKS + 1), "too many brackets, dots"),
    ("x = " + "[]" * toml_bounds.MAX_MARKS, "too many"),
])
def test_text_beyond_a_bound_is_a_model_error_naming_it(text, match):
    with pytest.raises(_model.ModelError, match=match):
        _model.loads(text, "m.toml")


def test_text_within_the_bounds_parses_as_before():
    # dots inside strings, values and comments are not key segments
    text = GOOD + '\n# a.b.c.d.e.f.g.h.i.j\n'
    assert _model.loads(text).to_toml() == GOOD
    assert toml_bounds.check('a."b.c.d.e.f.g.h.i.j".k = 1.5  # x.y\nv = [1.5, 2.5, 3.5, 4.5]\n'
                             's = """x.\\"""y.z.w.v.u.t.s.r"""\n')
    assert toml_bounds.check(b"x = {a = 1, b.c = 2}\n[t.u.v]\n") == "x = {a = 1, b.c = 2}\n[t.u.v]\n"


HOSTILE = {
    "trackers = 5": "trackers must be an array of tables",
    "trackers = [5]": "trackers must be an array of tables",
    "connections = 'x'": "connections must be an array of tables",
}


@pytest.mark.parametrize("line", sorted(HOSTILE))
def test_hostile_top_level_types_are_model_errors(line):
    text = f'name = "m"\n{line}\n[sensor]\nwidth = 100\nheight = 100\n'
    with pytest.raises(_model.ModelError, match=HOSTILE[line]):
        _model.loads(text, "m.toml")


@pytest.mark.parametrize("old,new,match", [
    ('a = "r0c0"', "a = [1]", "unknown tracker id"),
    ('springs = ["cartesian"]', "springs = [{}]", "unknown spring kind"),
    ('springs = ["cartesian"]', 'springs = "cartesian"', "springs must be a list"),
])
def test_hostile_connection_types_are_model_errors(old, new, match):
    with pytest.raises(_model.ModelError, match=match):
        _model.loads(GOOD.replace(old, new, 1), "m.toml")


def test_params_that_are_not_a_table_are_a_param_error(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text('params = "x"\n')
    with pytest.raises(_params.ParamTypeError, match="must be a table"):
        _params.load(p)
    with pytest.raises(_model.ModelError, match=r"\[params\] must be a table"):
        _model.loads('name = "m"\nparams = "x"\n[sensor]\nwidth = 9\nheight = 9\n', "m")


@pytest.mark.parametrize("bad", ["=cmd()", "a,b", "a\nb", "-x", "+1", "@x", "a b", "", "x" * 33,
                                 "a\x07", "é"])
def test_tracker_ids_outside_the_safe_set_are_refused(bad):
    from springtrack.model import ShapeModel, TrackerSpec
    with pytest.raises(_model.ModelError, match="is not a tracker id.*letters, digits"):
        ShapeModel("m", 100, 100, [TrackerSpec(bad, 10.0, 10.0, (4.0, 0.0, 4.0))], [])


def test_cli_refuses_a_deep_key_model_fast_with_bounded_memory(tmp_path):
    """A 60 KB ``--model`` once took 11 s and 3.5 GB in ``springtrack track``."""
    m = tmp_path / "deep.toml"
    m.write_text(deep_key(60_000))
    ev = tmp_path / "e.npy"
    import numpy as np
    from springtrack.events import EVENT_DTYPE
    np.save(ev, np.zeros(10, EVENT_DTYPE))
    r = subprocess.run([sys.executable, str(HERE / "peak_rss.py"), "400", "springtrack", "track",
                        str(ev), "--model", str(m), "--out", str(tmp_path / "o.csv")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode not in (0, 99), r.stderr
    assert "dotted key" in r.stderr and "Traceback" not in r.stderr


def worst_legal_upload() -> str:
    """A text at the bounds' edge that tomllib must parse in full: a flat table of as many
    keys as allowed, padded with comments to the size limit (it is then refused: unknown
    keys)."""
    body = "".join(f"k{i} = {i}\n" for i in range(toml_bounds.MAX_ITEMS - 10))
    pad = toml_bounds.MAX_TEXT_BYTES - len(body) - 1
    return body + "#" * pad + "\n"


def test_worst_legal_upload_keeps_the_link_answering_other_sessions():
    """A 120 KB deep-key upload once made every session deaf for 90 s and grew the firmware
    to 13.8 GB; now it is refused at once, and the worst text within the bounds is
    validated off the link's thread while a monitor's STATS are answered within 1 s."""
    served = TcpServed(SimEngine())
    try:
        served.engine.run()
        with Device(served.url, name="op") as op, \
                Device(served.url, name="mon", role=Role.MONITOR) as mon:
            t0 = time.perf_counter()
            with pytest.raises(Nacked, match="dotted key") as e:
                op.load_model(deep_key(120_000))
            assert e.value.code == Nack.INVALID_MODEL
            assert time.perf_counter() - t0 < 3
            text = worst_legal_upload()
            assert len(text.encode()) == toml_bounds.MAX_TEXT_BYTES
            import threading
            errors: list = []
            up = threading.Thread(target=lambda: errors.append(_upload(op, text)))
            up.start()
            worst = 0.0
            while up.is_alive():
                t = time.perf_counter()
                assert mon.stats()["session.role"] == "monitor"
                worst = max(worst, time.perf_counter() - t)
            up.join()
            assert worst < 1.0, f"a STATS took {worst:.2f} s during the upload"
            assert isinstance(errors[0], Nacked) and "unknown top-level key" in str(errors[0])
            st = mon.stats()
            assert st["link.uploads_validated"] == 2
            assert op.load_model(_model.grid3x3()) > 0      # a valid model still goes in
    finally:
        served.close()


def _upload(dev, text):
    try:
        dev.load_model(text)
    except Nacked as e:
        return e
    return None


# ---- fuzz target: model text ----------------------------------------------------------
SNIPPETS = st.sampled_from(["a.", "[", "]", "{", "}", "=", ",", '"', "'", '"""', "'''", "\n",
                            "#", "\\", "1", "x", " ", "[[trackers]]\n", "1e999", "nan",
                            "9" * 50, "a = ", ".b", "[[", "]]"])


def _fuzz_text(base: str, cuts: list) -> str:
    for pos, snip in cuts:
        p = pos % (len(base) + 1)
        base = base[:p] + snip + base[p:]
    return base


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.integers(0, 10_000), st.one_of(SNIPPETS, st.text(max_size=8))),
                max_size=12), st.integers(1, 40))
def test_fuzz_model_text_only_model_errors(cuts, repeat):
    """Mutated model text, and snippets repeated: a ModelError (a ValueError) or a model,
    never another exception, never beyond the bounds' cost."""
    text = _fuzz_text(GOOD, cuts)
    text = text + "".join(s for _, s in cuts) * repeat
    try:
        toml_bounds.check(text)
    except (toml_bounds.TomlBoundsError, UnicodeError):
        pass
    try:
        m = _model.loads(text, "fuzz")
    except _model.ModelError:
        return
    assert _model.loads(m.to_toml()).to_toml() == m.to_toml()


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=400))
def test_fuzz_params_text_only_param_errors(text):
    try:
        _params.from_mapping(_params.parse_toml(text, "fuzz"))
    except _params.ParamError:
        pass


def test_instance_labels_in_tracker_ids_are_safe_for_csv():
    """Ids shared by several instances are prefixed with the instance's label, made from
    the model's name (free text): its unsafe characters become '_'."""
    import dataclasses
    from springtrack.instances import _labels, unique_ids
    from springtrack.limits import TRACKER_ID
    m = dataclasses.replace(_model.grid3x3(), name="=cmd(), a\\nb")
    labels = _labels([m, m])
    assert labels == ["_cmd____a_nb#1", "_cmd____a_nb#2"]
    from types import SimpleNamespace as NS
    ids = unique_ids([NS(model=m, label=labels[0]), NS(model=m, label=labels[1])])
    assert all(TRACKER_ID.fullmatch(i.replace("#", "").replace("/", "")) for i in ids)
