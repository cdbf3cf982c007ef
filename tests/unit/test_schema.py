"""The site file's one schema (pfdoa.schema): the validators take every range, type, default
and known key from it; docs/site-file.md and examples/site.full.toml are generated from it
and current; the full example passes every validator (`pfdoa replay` with it:
tests/io/test_schema_replay.py)."""

from __future__ import annotations

import copy
import logging
from dataclasses import fields

import pytest

from pfdoa import _toml as tomllib
from pfdoa import schema
from pfdoa.errors import ConfigError
from pfdoa.estimators import _CLASSES
from pfdoa.estimators.common import OPTION_CHECKS
from pfdoa.estimators.pf_model import MAX_EXPONENT, MIN_EXPONENT
from pfdoa.gateway.beacons import BeaconsConfig, PeersConfig, beacons_config
from pfdoa.gateway.inputs.espresense import EspresenseConfig, espresense_config
from pfdoa.gateway.setup import build_estimator
from pfdoa.mqtt.config import MqttTable, mqtt_table
from pfdoa.radiomap import parse_radio_map
from pfdoa.readings.config import GatewayConfig, OutputConfig, gateway_config, output_config
from pfdoa.ros2.config import Ros2Table, ros2_settings
from pfdoa.site import load_site, parse_site

pytestmark = pytest.mark.unit

ROOT = schema.ROOT  # the repository (the schema writes its documents there)
FULL = schema.EXAMPLE_PATH


def full_document() -> dict:
    return tomllib.loads(FULL.read_text(encoding="utf-8"))


def validate(doc: dict) -> None:
    """Every validator of a site file, as the commands run them."""
    site = parse_site(doc, "full.toml")
    s = site.sections
    gateway_config(s, "full.toml")
    output_config(s, "full.toml")
    beacons_config(s, "full.toml")
    mqtt_table(s, "full.toml")
    ros2_settings(s, "full.toml", environ={})
    if "espresense" in s:
        espresense_config(s, "full.toml", site.anchor_ids, site.radio.rssi_at_1m_dbm)
    build_estimator(site, None, 0, "full.toml")
    if "radio_map" in s:
        parse_radio_map(s["radio_map"], site.anchor_ids, "full.toml")


# A [[beacons]] entry of each kind (keys as examples/site.full.toml shows them).
def beacon_entry(kind: str) -> dict:
    return {k.key: k.example if k.example is not None else k.default
            for k in schema.keys_of("beacons", array=True, kind=kind)
            if (k.required or k.key in ("kind",)) and k.key != "key_file"} | {"kind": kind}


def placed(doc: dict, row: schema.Key, value) -> tuple[dict, str]:
    """``doc`` with ``row``'s key set to ``value``, and the key the error must name."""
    doc = copy.deepcopy(doc)
    if row.table == "beacons" and row.array:
        kind = next(k for k in row.kinds or ("ibeacon",) if k != "pfdoa_auth")
        doc["beacons"] = [beacon_entry(kind) | {row.key: value}]
        return doc, f"beacons[0].{row.key}"
    table = doc.setdefault(row.table, [{}] if row.array else {})
    if row.array:
        table[0][row.key] = value
        return doc, f"{row.table}[0].{row.key}"
    table[row.key] = value
    return doc, f"{row.table}.{row.key}"


def test_the_generated_docs_and_example_are_current():
    assert (ROOT / "docs" / "site-file.md").read_text(encoding="utf-8") == schema.render_markdown(), \
        "docs/site-file.md is stale: run python -m pfdoa.schema"
    assert FULL.read_text(encoding="utf-8") == schema.render_toml(), \
        "examples/site.full.toml is stale: run python -m pfdoa.schema"
    assert schema.main(["--check"]) == 0


def test_the_check_finds_a_stale_file(tmp_path, monkeypatch):
    doc = tmp_path / "site-file.md"
    doc.write_text(schema.render_markdown().replace("| `mode` |", "| `mood` |"))
    monkeypatch.setattr(schema, "DOC_PATH", doc)
    monkeypatch.setattr(schema, "EXAMPLE_PATH", tmp_path / "site.full.toml")
    assert schema.main(["--check"]) == 1 and not (tmp_path / "site.full.toml").exists()
    assert schema.main([]) == 0 and schema.main(["--check"]) == 0
    assert doc.read_text() == schema.render_markdown()


def test_every_key_is_documented_and_in_the_full_example():
    md = (ROOT / "docs" / "site-file.md").read_text()
    text = FULL.read_text()
    for k in schema.KEYS:
        assert f"| `{k.key}` |" in md, k.name
        assert f"\n{k.key} = " in text or f"\n# {k.key} = " in text, k.name
    for table in schema.TABLES:
        assert f"## `[{table}]`" in md or f"## `[[{table}]]`" in md
    doc = full_document()
    set_keys = {(t, k) for t, v in doc.items() for e in (v if isinstance(v, list) else [v]) for k in e}
    commented = {(k.table, k.key) for k in schema.KEYS if k.commented or (k.table == "beacons" and k.array)}
    assert {(k.table, k.key) for k in schema.KEYS} - commented <= set_keys
    assert len(schema.KEYS) > 100 and len(schema.TABLES) == 13


def test_the_full_example_passes_every_validator_and_loads():
    validate(full_document())
    site = load_site(FULL)
    assert site.name == "example-lab" and len(site.anchors) == 4 and site.area is not None
    assert site.sections["estimator"]["particles"] == 2000


def test_the_dataclasses_defaults_are_the_schemas():
    for cls, table in ((GatewayConfig, "gateway"), (OutputConfig, "output"), (MqttTable, "mqtt"), (Ros2Table, "ros2")):
        assert {f.name: f.default for f in fields(cls)} == schema.defaults(table), table
    assert {f.name: f.default for f in fields(BeaconsConfig) if f.name in schema.names_of("beacons", array=False)} \
        == schema.defaults("beacons", array=False)
    peers = {f.name: f.default for f in fields(PeersConfig) if f.name != "index" and f.name != "name"}
    assert peers == schema.defaults("beacons", array=True, kind="anchors")
    esp = {f.name: f.default for f in fields(EspresenseConfig) if f.name in schema.names_of("espresense")
           and f.name != "rooms"}
    assert esp == schema.defaults("espresense")
    assert set(OPTION_CHECKS) == set(schema.names_of("estimator"))
    for name, cls in _CLASSES.items():  # every option an estimator takes has its row
        assert set(cls.OPTIONS) <= set(schema.names_of("estimator")), name
    # The range pf-doa models is the estimator's own clamp (stated once, checked here).
    assert schema.row("radio", "path_loss_exponent").modelled == (MIN_EXPONENT, MAX_EXPONENT)


RANGED = [k for k in schema.KEYS if k.type in ("int", "float") and k.max is not None]


@pytest.mark.parametrize("row", RANGED, ids=lambda k: f"{k.name}{'[]' if k.array else ''}:{','.join(k.kinds)}")
def test_every_validator_takes_the_range_from_the_schema(row):
    base = full_document()
    over = int(row.max) + 1 if row.type == "int" else row.max * 1.5 + 1.0
    doc, where = placed(base, row, over)
    with pytest.raises(ConfigError) as e:
        validate(doc)
    assert e.value.key == where and e.value.problem.startswith(f"must be in {row.range_text()}"), e.value
    assert repr(over) in e.value.problem
    # ... and the bounds themselves are allowed.
    for edge in (row.min, row.max):
        if edge is not None and not row.min_open:
            doc, _ = placed(base, row, int(edge) if row.type == "int" else float(edge))
            # An anchor at an edge is off the example's floors and maps; a backoff at an edge
            # may break its pair's order (min <= max): their own checks.
            if row.table == "estimator":  # (a million particles is allowed, and slow to build)
                assert OPTION_CHECKS[row.key](row.key, edge) == edge
            elif row.table != "anchors" and not row.key.startswith("reconnect_"):
                validate(doc)


@pytest.mark.parametrize("table", [t for t in schema.TABLES if t not in ("estimator",)])
def test_every_validator_refuses_a_key_the_schema_does_not_list(table):
    row = schema.keys_of(table)[0]
    fake = schema.Key(row.table, "nosuchkey", "int", "", array=row.array, kinds=row.kinds)
    doc, where = placed(full_document(), fake, 1)
    with pytest.raises(ConfigError) as e:
        validate(doc)
    assert e.value.key == where and "unknown key" in e.value.problem


@pytest.mark.parametrize("row", [k for k in schema.KEYS if k.choices and k.type == "string"], ids=lambda k: k.name)
def test_choices_come_from_the_schema(row):
    doc, where = placed(full_document(), row, "nosuchchoice")
    with pytest.raises(ConfigError) as e:
        validate(doc)
    assert e.value.key == where and "must be one of" in e.value.problem
    for choice in row.choices:
        if row.key != "kind":
            validate(placed(full_document(), row, choice)[0])


def test_an_exponent_below_what_pf_doa_models_is_noted_once(tmp_path, caplog):
    text = FULL.read_text().replace("path_loss_exponent = 2.0", "path_loss_exponent = 1.1")
    low = tmp_path / "low.toml"
    low.write_text(text)
    caplog.set_level(logging.INFO)
    assert load_site(low).radio.path_loss_exponent == 1.1  # allowed: a fit of such a room is the site's
    assert load_site(low).radio.path_loss_exponent == 1.1
    noted = [r for r in caplog.records if "path_loss_exponent" in r.getMessage()]
    assert [r.levelno for r in noted] == [logging.INFO]  # handled by design: not a warning
    message = noted[0].getMessage()
    assert "radio.path_loss_exponent = 1.1 is below what pf-doa models (1.6-8)" in message
    assert "keeps 1.6" in message and "n / 1.6" in message
    caplog.clear()
    load_site(FULL)
    assert not [r for r in caplog.records if "path_loss_exponent" in r.getMessage()]
    with pytest.raises(ConfigError, match=r"radio.path_loss_exponent: must be in \[0.5, 10\], got 0.4"):
        parse_site(placed(full_document(), schema.row("radio", "path_loss_exponent"), 0.4)[0], "x.toml")
