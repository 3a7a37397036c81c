"""Every model in the registries, the user's and the bundled one, served by name: loaded on first use,
a bounded number kept, newest followed.

A request names a model as ``NAME`` (that model's newest servable version) or
``NAME:VERSION``; without one it gets the default (``RGB2CLOUD_MODEL``), which is
loaded at startup, never evicted, and what ``/readyz`` waits for. Others load on
first use, verified exactly as the default is, and at most ``max_loaded`` stay
loaded: the least recently used goes first.

The registry is read again on every request that names a model, so a version
published while the service runs (``contract.card.publish`` renames a finished
folder into place) is served without a restart. A version that fails verification
is refused with its reason and never replaces the one serving: ``NAME`` keeps
following the newest version that loads. A refused version is tried again only when
its card changes on disk.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from app.loading import LoadedModel, ModelLoadError, load_version
from app.settings import Settings
from contract.card import CARD_FILE, CardError, ModelCard, load_card
from contract.registries import Registries

log = logging.getLogger("rgb2cloud")
Key = tuple[str, str]


class UnknownModel(Exception):
    """No such model or version in the registry (HTTP 404); ``available`` says what there is."""

    def __init__(self, message: str, available: dict[str, list[str]]):
        super().__init__(message)
        self.message, self.available = message, available


class RefusedModel(Exception):
    """The version is in the registry but cannot be served (HTTP 409); the message says why."""

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


def parse_reference(reference: str) -> tuple[str, str | None]:
    """``NAME`` or ``NAME:VERSION`` -> (name, version or None)."""
    name, _, version = reference.strip().partition(":")
    return name, version or None


class ModelCatalog:
    """The loaded models, least recently used first, and the versions refused with their reasons."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self.default: LoadedModel | None = None
        self._loaded: OrderedDict[Key, LoadedModel] = OrderedDict()
        self._refused: dict[Key, tuple[str, float | None]] = {}
        self._loading: dict[Key, threading.Lock] = {}
        self._lock = threading.Lock()
        #: Called after a model loads or is unloaded (the app points it at its metrics).
        self.on_change: Callable[[ModelCatalog], None] = lambda _: None

    @property
    def registries(self) -> Registries:
        return Registries(self.settings.registry, self.settings.bundled_registry)

    def default_key(self) -> Key:
        """The default model's (name, version): ``RGB2CLOUD_MODEL``, else the bundled registry's model, else the
        only model there is, newest."""
        registries = self.registries
        models = registries.models()
        where = f"{registries.own} and {registries.bundled}"
        if not models:
            raise ModelLoadError(f"{where}: no published model (expected <name>/<version>/card.json)")
        if self.settings.model:
            name, version = parse_reference(self.settings.model)
        elif (bundled := registries.bundled_default()) is not None:
            name, version = bundled, None
        elif len(models) == 1:
            name, version = next(iter(models)), None
        else:
            raise ModelLoadError(f"{where}: several models {sorted(models)}; set RGB2CLOUD_MODEL=NAME or NAME:VERSION")
        try:
            return self._resolve(name, version, models)
        except UnknownModel as e:
            raise ModelLoadError(e.message) from None

    def load_default(self) -> LoadedModel:
        """Load the default model (startup); a ModelLoadError stops the service."""
        key = self.default_key()
        model = load_version(self.registries.folder(*key), self.settings)
        with self._lock:
            self.default = model
            self._loaded[key] = model
        self.on_change(self)
        return model

    def get(self, reference: str) -> LoadedModel:
        """The model ``NAME`` or ``NAME:VERSION`` names, loading it if needed (blocking: call off the event loop)."""
        name, version = parse_reference(reference)
        models = self.registries.models()
        key = self._resolve(name, version, models)
        while True:
            model = self._cached(key)
            if model is not None:
                return model
            try:
                return self._load(key)
            except RefusedModel:
                if version is not None:
                    raise
                key = self._resolve(name, None, models)  # the next newest that may load

    def loaded(self) -> list[LoadedModel]:
        with self._lock:
            return list(self._loaded.values())

    def refusal(self, name: str, version: str) -> str | None:
        with self._lock:
            refused = self._refused.get((name, version))
        return refused[0] if refused else None

    def _resolve(self, name: str, version: str | None, models: dict[str, list[str]]) -> Key:
        if name not in models:
            raise UnknownModel(f"no model {name!r} in the registries", models)
        if version is not None:
            if version not in models[name]:
                raise UnknownModel(f"model {name!r} has no version {version!r}", models)
            return name, version
        servable = [v for v in models[name] if not self._still_refused((name, v))]
        if not servable:
            reasons = "; ".join(f"{v}: {self.refusal(name, v)}" for v in models[name])
            raise RefusedModel(f"no version of {name!r} can be served ({reasons})")
        return name, servable[-1]

    def _card_stamp(self, key: Key) -> float | None:
        try:
            return (self.registries.folder(*key) / CARD_FILE).stat().st_mtime
        except OSError:
            return None

    def _still_refused(self, key: Key) -> bool:
        with self._lock:
            refused = self._refused.get(key)
        return refused is not None and refused[1] == self._card_stamp(key)

    def _cached(self, key: Key) -> LoadedModel | None:
        with self._lock:
            model = self._loaded.get(key)
            if model is not None:
                self._loaded.move_to_end(key)
        return model

    def _load(self, key: Key) -> LoadedModel:
        with self._lock:
            loader = self._loading.setdefault(key, threading.Lock())
        with loader:  # one load per version at a time; the others wait for it and share it
            model = self._cached(key)
            if model is not None:
                return model
            if self._still_refused(key):
                raise RefusedModel(f"{key[0]}:{key[1]} cannot be served: {self.refusal(*key)}")
            stamp = self._card_stamp(key)
            try:
                model = load_version(self.registries.folder(*key), self.settings)
            except ModelLoadError as e:
                with self._lock:
                    self._refused[key] = (str(e), stamp)
                log.error("refused %s:%s: %s", *key, e)
                raise RefusedModel(f"{key[0]}:{key[1]} cannot be served: {e}") from None
            with self._lock:
                self._refused.pop(key, None)
                self._loaded[key] = model
                self._evict()
            log.info(
                "loaded %s (warm-up %.2fs; %s)",
                model.label,
                model.warmup_seconds,
                "; ".join(
                    [
                        f"{p} on {e}" + (f" ({model.chosen[p]})" if p in model.chosen else "")
                        for p, e in model.engines.items()
                    ]
                    + [f"no {p}: {why}" for p, why in model.unserved.items()]
                    + [f"not {candidate}: {why}" for candidate, why in model.dropped.items()]
                ),
            )
        self.on_change(self)
        return model

    def _evict(self) -> None:
        """Drop least recently used models beyond the bound; the default stays (caller holds the lock)."""
        for key in list(self._loaded):
            if len(self._loaded) <= self.settings.max_loaded:
                break
            if self._loaded[key] is not self.default:
                log.info("unloaded %s:%s (least recently used)", *key)
                del self._loaded[key]

    def describe(self) -> dict[str, Any]:
        """What /v1/models shows: every model and version, loaded or refused, with its card's summary."""
        loaded = {(m.card.name, m.card.version): m for m in self.loaded()}
        models = []
        registries = self.registries
        for name, versions in registries.models().items():
            entries = []
            for version in reversed(versions):
                entry: dict[str, Any] = {"version": version, "loaded": (name, version) in loaded}
                refused = self.refusal(name, version) if self._still_refused((name, version)) else None
                try:
                    entry["card"] = card_summary(load_card(registries.folder(name, version)))
                    entry["card"]["precisions"] = self._precisions(entry["card"], loaded.get((name, version)))
                    if (name, version) in loaded:
                        entry["serving"] = self._serving(loaded[(name, version)])
                except CardError as e:
                    refused = refused or str(e)
                entry["refused"] = refused
                entries.append(entry)
            models.append({"name": name, "versions": entries})
        default = self.default
        return {
            "default": None if default is None else {"name": default.card.name, "version": default.card.version},
            "max_loaded": self.settings.max_loaded,
            "models": models,
        }

    def _precisions(self, summary: dict[str, Any], model: LoadedModel | None) -> list[str]:
        """The precisions this service can run for a version: a loaded one's that passed their checks here,
        else the graphs its card ships that this engine runs."""
        if model is not None:
            return list(model.generators)
        return summary["precisions"] if self.settings.engine != "torchscript" else ["fp32"]

    @staticmethod
    def _serving(model: LoadedModel) -> dict[str, Any]:
        """How a loaded version runs here: each precision's engine and why it won, what auto serves, what was
        measured at load (generator ms on the check photo: the median, and the fastest and slowest run), how long its
        load's checks and measurements took, why any precision is not served, why any engine was left out of
        a precision another engine serves, and the photo they were checked on."""
        sample = model.card.sample
        return {
            "checked_on": f"the version's sample photo ({sample})"
            if sample
            else "a stand-in texture (app.loading.stand_in_photo): this version ships no sample photo",
            "engines": dict(model.engines),
            "chosen": dict(model.chosen),
            "auto": model.auto,
            "load_s": round(model.warmup_seconds, 2),
            "measured_ms": {k: round(v.median, 1) for k, v in model.measured.items()},
            "measured_range_ms": {k: [round(min(v.runs), 1), round(max(v.runs), 1)] for k, v in model.measured.items()},
            "unserved": dict(model.unserved),
            "dropped": dict(model.dropped),
        }


def card_summary(card: ModelCard) -> dict[str, Any]:
    """The parts of a card a person choosing a model needs: when, what from, how good, which camera, which
    graphs (an int8 one ONNX Runtime serves with ``precision=int8``)."""
    fit = card.training.fit
    return {
        "created": card.created.isoformat(),
        "camera": card.camera.as_dict(),
        "inference": card.inference.model_dump(),
        "data": [{"name": d.name, "licence": d.licence, "via": d.via} for d in card.training.data],
        "fit": None if fit is None else fit.model_dump(include={"data", "start_from", "start_model"}),
        "metrics": [{"split": m.split, "label": m.label, "delta1": m.delta1, "rel": m.rel} for m in card.metrics],
        "precisions": ["fp32", "int8"] if card.int8 else ["fp32"],
    }
