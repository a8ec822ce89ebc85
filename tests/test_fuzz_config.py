"""Fuzzing the configuration loaders (hypothesis): plant/emulator TOML files and ``--set``
overrides, bus specifications with fault options, the gateway's limits, and the command line.

Property: bad input ends as one clear error of the documented kind (ModelError, BusSpecError,
ParameterError → one line, exit 2), never another exception, and what is accepted is finite
and in range.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from gateway import GatewayConfig, SafetyLimits
from gateway.errors import ParameterError
from plant.config import load_plant_config
from plant.params import ModelError
from plant.config import INITIAL_PARAMS, load_plant_config as load_emulator_config

MAX_INITIAL_FORCE_KGF = INITIAL_PARAMS[0].upper
from standbus import BusSpec, BusSpecError, open_bus

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                        HealthCheck.function_scoped_fixture])

# -- TOML documents ------------------------------------------------------------------------------
scalars = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**20, 10**20), st.booleans(),
    st.text(max_size=8), st.sampled_from([0.0, 1.0, -1.0, 120.0, 0.05, 1e308, -1e308]),
    st.lists(st.integers(0, 9), max_size=3))
keys = st.one_of(st.sampled_from(["g", "tau", "delta", "boost", "decay", "noise_kgf", "resolution_kgf",
                                  "range_kgf", "force_kgf", "enabled", "time_constant", "width"]),
                 st.from_regex(r"[a-z_]{1,8}", fullmatch=True))
tables = st.dictionaries(keys, scalars, max_size=5)
effects = st.dictionaries(st.one_of(st.sampled_from(["reversal", "lag", "deadzone", "saturation",
                                                     "asymmetry", "leakage", "oscillation"]),
                                    st.from_regex(r"[a-z]{1,6}", fullmatch=True)), tables, max_size=3)
documents = st.fixed_dictionaries({}, optional={
    "base": tables, "sensor": tables, "initial": tables, "effects": effects,
    "model": st.one_of(st.sampled_from(["base", "base+reversal", "base+lag", "reversal", ""]), st.text(max_size=10)),
    "extra": tables})


def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return json.dumps(v)


def to_toml(doc: dict) -> str:
    lines = []
    if "model" in doc:
        lines.append(f"model = {toml_value(doc['model'])}")
    for name, table in doc.items():
        if name in ("model", "effects"):
            continue
        lines.append(f"[{name}]")
        lines += [f"{k} = {toml_value(v)}" for k, v in table.items()]
    for name, table in (doc.get("effects") or {}).items():
        lines.append(f"[effects.{name}]")
        lines += [f"{k} = {toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def assert_runnable(config) -> None:
    params = config.model.params()
    assert all(isinstance(v, float) and math.isfinite(v) for v in params.values()), params
    assert math.isfinite(config.initial_force_kgf) and abs(config.initial_force_kgf) <= MAX_INITIAL_FORCE_KGF
    sensor = config.dynamometer(0)
    assert all(math.isfinite(getattr(sensor, k)) for k in ("noise_kgf", "resolution_kgf", "range_kgf"))


@FUZZ
@given(doc=documents)
@example(doc={"initial": {"force_kgf": math.nan}})
@example(doc={"initial": {"force_kgf": "x"}})
@example(doc={"base": {"g": math.inf}})
def test_emulator_config_files_load_or_fail_clearly(tmp_path, doc):
    path = tmp_path / "plant.toml"
    path.write_text(to_toml(doc))
    try:
        config = load_emulator_config(path)
    except ModelError as exc:
        assert str(exc)
        return
    assert_runnable(config)


@FUZZ
@given(text=st.text(max_size=200))
def test_any_text_as_a_config_file(tmp_path, text):
    path = tmp_path / "plant.toml"
    path.write_text(text)
    try:
        assert_runnable(load_emulator_config(path))
    except ModelError:
        pass


@FUZZ
@given(overrides=st.dictionaries(st.one_of(keys, st.sampled_from(["initial.force_kgf", "sensor.noise_kgf",
                                                                  "reversal.boost", "sensor.range_kgf"])),
                                 st.floats(allow_nan=True, allow_infinity=True), max_size=4),
       model=st.one_of(st.none(), st.sampled_from(["base", "base+reversal", "base+lag+deadzone", "bogus"])))
def test_set_overrides_load_or_fail_clearly(overrides, model):
    try:
        config = load_emulator_config(None, model, overrides)
    except ModelError:
        return
    assert_runnable(config)


@pytest.mark.parametrize("text", ['[initial]\nforce_kgf = nan\n', '[initial]\nforce_kgf = "x"\n',
                                  'base = 3\n', '[effects]\nreversal = 3\n'])
def test_load_plant_config_itself_rejects_these(tmp_path, text):
    path = tmp_path / "plant.toml"
    path.write_text(text)
    with pytest.raises(ModelError):
        config = load_plant_config(path)
        assert math.isfinite(config.initial_force_kgf)


# -- bus specifications -----------------------------------------------------------------------------
@FUZZ
@given(text=st.text(max_size=60))
def test_bus_spec_parsing_never_raises_anything_else(text):
    try:
        spec = BusSpec.parse(text)
    except BusSpecError as exc:
        assert str(exc)
        return
    assert spec.interface and BusSpec.parse(str(spec)).interface == spec.interface


option_values = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                          st.integers(-5, 10**6).map(str), st.sampled_from(["true", "x", "", "0x080-0x4FF", "9-1"]),
                          st.text(alphabet="0123456789.-xabcdefn", max_size=8))


@settings(max_examples=150, deadline=None)
@given(options=st.dictionaries(st.sampled_from(["drop", "delay_ms", "fault_ids", "seed", "fd",
                                                "receive_own_messages", "bogus"]),
                               option_values, max_size=4))
def test_udp_loopback_options_open_or_fail_clearly(options):
    spec = "udp_loopback:fuzz-options" + "".join(f",{k}={v}" for k, v in options.items())
    assume("," not in "".join(options.values()) and "=" not in "".join(options.values()))
    try:
        bus = open_bus(spec)
    except BusSpecError as exc:
        assert "udp_loopback" in str(exc) or "bus" in str(exc)
        return
    try:
        if bus.faults is not None:
            assert 0 <= bus.faults.spec.drop <= 1 and 0 <= bus.faults.spec.delay_s <= 10
    finally:
        bus.shutdown()


# -- the gateway's own configuration ------------------------------------------------------------------
floats = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -1.0, 1e9]))


@FUZZ
@given(force=floats, cmd=floats, slew=st.one_of(st.none(), floats), err=st.one_of(st.none(), floats),
       hb=floats, stale=st.integers(-5, 10**6), overrun=floats, period=floats,
       action=st.sampled_from(["hold", "unload", "zero", "indicate", "explode", ""]))
def test_gateway_limits_are_valid_or_refused(force, cmd, slew, err, hb, stale, overrun, period, action):
    limits = SafetyLimits(force_limit_kgf=force, command_limit_pct=cmd, slew_pct_per_s=slew,
                          error_limit_kgf=err, heartbeat_timeout_s=hb, stale_cycles=stale,
                          overrun_limit_s=overrun, force_action=action)
    try:
        GatewayConfig(period_s=period, limits=limits).validate()
    except ParameterError:
        return
    for v in (force, cmd, hb, overrun, period, slew or 1.0, err or 1.0):
        assert math.isfinite(v) and v >= 0
    assert action in ("hold", "unload", "zero", "indicate") and stale >= 1


@pytest.mark.parametrize("argv, words", [
    (["run", "meander", "--force-limit", "nan"], "force_limit_kgf = nan"),
    (["run", "meander", "--force-limit", "inf"], "force_limit_kgf = inf"),
    (["run", "meander", "--command-limit", "250"], "command_limit_pct = 250"),
    (["run", "meander", "--slew-limit", "-3"], "slew_pct_per_s = -3"),
    (["run", "meander", "--heartbeat-timeout", "50"], "must exceed the nodes' heartbeat period"),
    (["run", "meander", "--stale-cycles", "0"], "stale_cycles = 0"),
    (["run", "meander", "--sdo-timeout", "0"], "sdo_timeout_s = 0"),
    (["run", "meander", "--bus", "udp_loopback:x,drop=7"], "fault injection: drop=7"),
    (["emulate", "--set", "initial.force_kgf=nan"], "initial.force_kgf must be finite"),
    (["emulate", "--set", "initial.force_kgf=1e12"], "outside its physical range"),
])
def test_the_command_line_refuses_bad_safety_input_in_one_line(tmp_path, argv, words):
    if argv[0] == "run":
        argv = argv + ["--out", str(tmp_path / "never"), "--boot-timeout", "0.5"]
    res = subprocess.run([sys.executable, "-m", "stand", *argv], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2, res.stderr
    assert words in res.stderr and "Traceback" not in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
