"""Model cards across schema versions: old cards migrate on read, retired options are refused by name."""

from __future__ import annotations

import json
import shutil

import pytest
from conftest import REPO

from contract.card import SCHEMA_VERSION, CardError, load_card, migrate_card, publish, verify_files
from contract.spec import GeneratorSpec, InferenceSettings

BUNDLED = REPO / "weights" / "rgb2cloud-7scenes" / "0.8.0"


def test_the_bundled_schema_1_card_loads_through_the_migration():
    on_disk = json.loads((BUNDLED / "card.json").read_text())
    assert on_disk["schema_version"] == 1 and "median_radius" in on_disk["generator"]  # never rewritten
    card = load_card(BUNDLED)
    verify_files(BUNDLED, card)
    assert card.schema_version == SCHEMA_VERSION
    assert card.generator == GeneratorSpec(
        ngf=16, n_downsample=3, n_blocks=6, dropout=0.5, work_scale=2, dilations=[1, 2, 4, 8, 4, 2]
    )
    assert card.inference == InferenceSettings(median_radius=2, median_sigma=0.2, median_spacing=4)
    assert card.input_multiple == card.generator.input_multiple == 16


@pytest.mark.parametrize(
    "option,value", [("skips", True), ("global_offset", True), ("flip_average", True), ("upsample_sigma", 0.4)]
)
def test_a_card_that_turned_on_a_retired_option_is_refused_by_name(tmp_path, option, value):
    card = json.loads((BUNDLED / "card.json").read_text())
    card["generator"][option] = value
    folder = tmp_path / "x" / "1.0.0"
    shutil.copytree(BUNDLED, folder)
    (folder / "card.json").write_text(json.dumps(card))
    with pytest.raises(CardError, match=rf"card\.json: .*generator\.{option} is on, and that option was retired"):
        load_card(folder)


def test_retired_options_at_their_off_value_are_dropped_and_nothing_else_is():
    old = {"schema_version": 1, "generator": {"ngf": 8, "skips": False, "upsample_sigma": 0.0, "median_sigma": 0.3}}
    assert migrate_card(old) == {
        "schema_version": SCHEMA_VERSION,
        "generator": {"ngf": 8},
        "inference": {"median_sigma": 0.3},
    }
    current = {"schema_version": SCHEMA_VERSION, "generator": {"ngf": 8, "skips": False}}
    assert migrate_card(current) == current  # a current card is validated as it is: the stray key is an error
    with pytest.raises(ValueError, match="schema_version 7 is not one this reader knows"):
        migrate_card({"schema_version": 7})


def test_a_current_card_with_an_unknown_key_is_refused(tmp_path):
    folder = tmp_path / "x" / "1.0.0"
    shutil.copytree(BUNDLED, folder)
    card = load_card(BUNDLED).model_dump(mode="json")
    card["generator"]["skips"] = False
    (folder / "card.json").write_text(json.dumps(card))
    with pytest.raises(CardError, match="skips"):
        load_card(folder)
    (folder / "card.json").write_text("[1, 2]")
    with pytest.raises(CardError, match="expected a JSON object"):
        load_card(folder)


def test_a_schema_2_card_drops_its_unread_output_text_and_names_the_start_as_everywhere_else():
    old = {
        "schema_version": 2,
        "output": "1 channel, tanh range [-1, 1]; metres via depth_encoding",
        "training": {"fit": {"started_from": "weights/rgb2cloud-7scenes/0.8.1", "budget_min": 30.0}},
    }
    migrated = migrate_card(old)
    assert migrated == {
        "schema_version": SCHEMA_VERSION,
        "training": {"fit": {"start_from": "weights/rgb2cloud-7scenes/0.8.1", "budget_min": 30.0}},
    }
    assert old["training"]["fit"]["started_from"]  # the input is untouched


def test_a_schema_4_card_s_int8_sample_is_the_card_s_sample_and_its_files_still_verify():
    folder = REPO / "weights" / "rgb2cloud-7scenes" / "0.9.1"
    on_disk = json.loads((folder / "card.json").read_text())
    assert on_disk["schema_version"] == 4 and on_disk["int8"]["sample"] == "int8-sample.png"  # never rewritten
    card = load_card(folder)
    verify_files(folder, card)
    assert card.sample == "int8-sample.png"
    assert load_card(BUNDLED).sample is None  # published before any version shipped one


def test_a_card_naming_a_sample_it_does_not_list_is_refused_at_publish_and_at_load(tmp_path):
    folder = REPO / "weights" / "rgb2cloud-7scenes" / "0.9.1"
    card = load_card(folder).model_copy(update={"name": "copy"})
    files = {name: folder / name for name in card.files if name != card.sample}
    with pytest.raises(CardError, match=r"names files it is not published with: \{'sample': 'int8-sample.png'\}"):
        publish(tmp_path, card, files)
    assert not (tmp_path / "copy").exists()  # nothing half-published
    published = publish(tmp_path, card.model_copy(update={"sample": None}), files)
    on_disk = json.loads((published / "card.json").read_text())
    on_disk["sample"] = "int8-sample.png"  # a card edited by hand to name a file it does not list
    (published / "card.json").write_text(json.dumps(on_disk))
    with pytest.raises(CardError, match=r"names files it does not list: \{'sample': 'int8-sample.png'\}"):
        verify_files(published, load_card(published))
