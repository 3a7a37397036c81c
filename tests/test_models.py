"""Many models, one service, over real HTTP: chosen per request, loaded on first use, LRU-bounded, hot-published.

The registry here holds versions published with ``contract.card.publish``, the function
``rgb2cloud export`` and ``fit`` publish with, copied from the tiny trained model.
"""

from __future__ import annotations

import io

import httpx
import numpy as np
import pytest
from conftest import TUM_FRAME
from PIL import Image

from contract.card import CARD_FILE, ONNX_FILE, load_card, publish
from contract.errors import UserError
from contract.registries import Registries
from harness.service import running_service

PHOTO = (TUM_FRAME / "TUM_color.png").read_bytes()


def publish_copy(folder, registry, name: str, version: str):
    """The version in ``folder`` published again, as ``name version``, into ``registry``."""
    card = load_card(folder).model_copy(update={"name": name, "version": version})
    return publish(registry, card, {f: folder / f for f in card.files})


def publish_live(registry, name: str, version: str):
    """A new version in a registry a service is serving from."""
    return publish_copy(registry / "kitchen" / "1.0.0", registry, name, version)


def depth(url: str, model: str | None = None) -> httpx.Response:
    params = {"model": model} if model else None
    return httpx.post(f"{url}/depth", files={"image": ("p.png", PHOTO)}, params=params, timeout=60)


def loaded(url: str) -> dict[str, bool]:
    described = httpx.get(f"{url}/v1/models", timeout=10).json()
    return {f"{m['name']}:{v['version']}": v["loaded"] for m in described["models"] for v in m["versions"]}


@pytest.fixture
def site_registry(registry, tmp_path):
    """Three site models: the default (kitchen), lab with two versions, office."""
    target = tmp_path / "weights"
    for name, version in [("kitchen", "1.0.0"), ("lab", "0.1.0"), ("lab", "0.2.0"), ("office", "0.1.0")]:
        publish_copy(registry / "tiny" / "0.1.0", target, name, version)
    return target


def test_models_are_chosen_per_request_and_the_newest_version_is_followed(site_registry):
    with running_service(
        registry=str(site_registry), model="kitchen", threads="1", max_loaded="4", engine="onnxruntime"
    ) as service:
        default = depth(service.url)
        assert (default.headers["x-model-name"], default.headers["x-model-version"]) == ("kitchen", "1.0.0")
        lab = depth(service.url, "lab")
        assert (lab.headers["x-model-name"], lab.headers["x-model-version"]) == ("lab", "0.2.0")
        assert depth(service.url, "lab:0.1.0").headers["x-model-version"] == "0.1.0"
        # The same weights under every name: the same depth, whichever model was asked for (on one engine: under
        # auto each version's engine is chosen by its own timing at load, and two engines round differently).
        assert np.array_equal(_png(default.content), _png(lab.content))

        missing = depth(service.url, "garage")
        assert missing.status_code == 404
        assert "garage" in missing.json()["detail"] and missing.json()["available"]["lab"] == ["0.1.0", "0.2.0"]
        assert depth(service.url, "lab:9.9.9").status_code == 404

        # Published while the service runs: served at once, and "lab" now means it.
        publish_live(site_registry, "lab", "0.3.0")
        assert depth(service.url, "lab").headers["x-model-version"] == "0.3.0"
        publish_live(site_registry, "garage", "0.1.0")
        assert depth(service.url, "garage").headers["x-model-name"] == "garage"

        metrics = httpx.get(f"{service.url}/metrics", timeout=5).text
        assert 'model="lab:0.2.0",route="/depth",status="200"' in metrics
        assert 'model="kitchen:1.0.0",route="/depth",status="200"' in metrics


def _png(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im)


def test_a_corrupt_version_is_refused_and_never_disturbs_the_ones_serving(site_registry):
    with running_service(registry=str(site_registry), model="kitchen", threads="1") as service:
        assert depth(service.url, "lab").headers["x-model-version"] == "0.2.0"
        broken = publish_live(site_registry, "lab", "0.3.0")
        onnx_file = broken / ONNX_FILE
        onnx_file.write_bytes(onnx_file.read_bytes()[:-10])

        refused = depth(service.url, "lab:0.3.0")
        assert refused.status_code == 409
        assert "lab:0.3.0" in refused.json()["detail"] and "sha256" in refused.json()["detail"]
        # "lab" keeps following the newest version that loads; the default is untouched.
        assert depth(service.url, "lab").headers["x-model-version"] == "0.2.0"
        assert depth(service.url).headers["x-model-name"] == "kitchen"
        assert httpx.get(f"{service.url}/readyz", timeout=5).status_code == 200
        lab = next(m for m in httpx.get(f"{service.url}/v1/models", timeout=5).json()["models"] if m["name"] == "lab")
        newest = lab["versions"][0]
        assert newest["version"] == "0.3.0" and not newest["loaded"] and "sha256" in newest["refused"]

        # A card that changes on disk is tried again: a rewritten card is a new attempt (still refused here).
        (broken / CARD_FILE).write_text((broken / CARD_FILE).read_text())
        assert depth(service.url, "lab:0.3.0").status_code == 409


def test_least_recently_used_models_are_unloaded_beyond_the_bound(site_registry):
    with running_service(registry=str(site_registry), model="kitchen", threads="1", max_loaded="2") as service:
        assert loaded(service.url) == {
            "kitchen:1.0.0": True,
            "lab:0.2.0": False,
            "lab:0.1.0": False,
            "office:0.1.0": False,
        }
        depth(service.url, "lab")
        assert loaded(service.url)["lab:0.2.0"]
        depth(service.url, "office")  # the bound is 2: lab goes, the default always stays
        state = loaded(service.url)
        assert state["kitchen:1.0.0"] and state["office:0.1.0"] and not state["lab:0.2.0"]
        assert depth(service.url, "lab").status_code == 200  # loads again on demand
        state = loaded(service.url)
        assert state["kitchen:1.0.0"] and state["lab:0.2.0"] and not state["office:0.1.0"]
        metrics = httpx.get(f"{service.url}/metrics", timeout=5).text
        assert "rgb2cloud_models_loaded 2.0" in metrics
        assert 'rgb2cloud_model_weights_bytes{model="office:0.1.0"}' not in metrics


def test_several_models_need_a_default(site_registry):
    with (
        pytest.raises(RuntimeError, match=r"several models .* set RGB2CLOUD_MODEL"),
        running_service(registry=str(site_registry), threads="1"),
    ):
        pass


def test_a_card_whose_input_or_output_this_service_cannot_keep_is_refused(site_registry):
    """Every card field that changes what the numbers mean is checked: another input encoding, another grid."""
    for name, change in [
        ("bgr", {"input_encoding": "bgr, NCHW float32, value = uint8 / 255"}),
        ("grid", {"input_multiple": 7}),
    ]:
        folder = publish_copy(site_registry / "kitchen" / "1.0.0", site_registry, name, "0.1.0")
        card = load_card(folder).model_copy(update=change)
        (folder / CARD_FILE).write_text(card.model_dump_json(indent=2))
    with running_service(registry=str(site_registry), model="kitchen", threads="1") as service:
        refused = depth(service.url, "bgr")
        assert refused.status_code == 409 and "input_encoding 'bgr, NCHW" in refused.json()["detail"]
        refused = depth(service.url, "grid")
        assert refused.status_code == 409 and "input_multiple 7" in refused.json()["detail"]
        assert depth(service.url).status_code == 200


def test_a_bound_that_could_not_keep_a_named_model_is_refused_at_startup(site_registry):
    """With room for the default alone, every named model would be unloaded as soon as it loaded."""
    with (
        pytest.raises(RuntimeError, match=r"RGB2CLOUD_MAX_LOADED='1': Input should be greater than or equal to 2"),
        running_service(registry=str(site_registry), model="kitchen", threads="1", max_loaded="1"),
    ):
        pass


def test_the_bundled_registry_is_served_beside_the_users_and_is_the_default(registry, tmp_path):
    """The user's registry (where fit publishes) and the bundled one are served together: the bundled
    model is the default unless RGB2CLOUD_MODEL says otherwise, and a name in both is the user's."""
    bundled, own = tmp_path / "bundled", tmp_path / "own"
    publish_copy(registry / "tiny" / "0.1.0", bundled, "kitchen", "1.0.0")
    publish_copy(registry / "tiny" / "0.1.0", own, "my-room", "0.1.0")
    publish_copy(registry / "tiny" / "0.1.0", own, "kitchen", "2.0.0")
    with running_service(registry=str(own), bundled_registry=str(bundled), threads="1") as service:
        default = depth(service.url)
        assert (default.headers["x-model-name"], default.headers["x-model-version"]) == ("kitchen", "2.0.0")
        assert depth(service.url, "my-room").headers["x-model-name"] == "my-room"
        assert depth(service.url, "kitchen:1.0.0").status_code == 404  # the user's kitchen shadows the bundled
        assert set(loaded(service.url)) == {"kitchen:2.0.0", "my-room:0.1.0"}
    (own / "kitchen").rename(tmp_path / "moved")
    with running_service(registry=str(own), bundled_registry=str(bundled), threads="1") as service:
        assert depth(service.url).headers["x-model-name"] == "kitchen"  # the bundled one, not the only own model
        assert depth(service.url, "my-room").status_code == 200


def test_one_rule_says_which_registry_owns_a_name_and_an_empty_folder_owns_nothing(registry, tmp_path):
    bundled, own = tmp_path / "bundled", tmp_path / "own"
    publish_copy(registry / "tiny" / "0.1.0", bundled, "kitchen", "1.0.0")
    (own / "kitchen").mkdir(parents=True)  # what a failed publish once left behind
    registries = Registries(own, bundled)
    assert registries.owner("kitchen") == bundled and registries.folder("kitchen", "1.0.0").is_dir()
    assert registries.owner("office") is None
    publish_copy(registry / "tiny" / "0.1.0", own, "kitchen", "2.0.0")
    assert registries.owner("kitchen") == own
    with pytest.raises(UserError, match="a bundled model has this name"):
        Registries(own, bundled).check_new_name("kitchen", own)
    Registries(own, bundled).check_new_name("kitchen", bundled)  # publishing into the bundled registry itself


def test_a_failed_first_publish_leaves_no_folder_that_would_hide_a_bundled_model(registry, tmp_path):
    folder = registry / "tiny" / "0.1.0"
    card = load_card(folder).model_copy(update={"name": "kitchen"})
    with pytest.raises(FileNotFoundError):  # while copying, after the name's folder was made
        publish(tmp_path / "own", card, {ONNX_FILE: tmp_path / "missing.onnx", card.sample: folder / card.sample})
    assert not (tmp_path / "own" / "kitchen").exists()
