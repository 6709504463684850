"""The effective config: the experiment with every mode-dependent default resolved.

A ``null`` in the config means "the default of the image-formation mode" (``physical``: the
physically complete camera; ``article``: the article's flat model) or, for ``render.light_tree``,
of the render fidelity. :data:`MODE_DEFAULTS` is the one table of those defaults and
:func:`effective` the one place they are applied: the planner reads the resolved values
(:mod:`blendgen.pipeline.plan`), every sequence's post-processing record is resolved when it is
made (``SequencePost``), ``generate`` records the effective config in the manifest
(``effective_config``) and ``dockbench generate CONFIG --show-config`` prints it.

Changing what a mode turns on is a change of one row of :data:`MODE_DEFAULTS`.
"""

from __future__ import annotations

from typing import Any

from blendgen.config.models import Experiment, Sensor
from blendgen.physics.camera import sensor as sensor_model
from blendgen.physics.camera.sensor import BLOOM_FRACTION  # its source: physics/camera/sensor.py

#: Diffuse sky irradiance as a fraction of the direct sun's on a horizontal plane (clear sky:
#: about 0.1-0.3); our choice for the physical mode.
SKY_FRACTION_PHYSICAL = 0.25

#: config setting (dotted path) -> (value for null in physical mode, value for null in article mode)
MODE_DEFAULTS: dict[str, tuple[Any, Any]] = {
    "scene.sky_fraction": (SKY_FRACTION_PHYSICAL, 0.0),
    "scene.ambient": (True, False),
    "scene.world.surface": (True, False),
    "scene.world.caustics": (True, False),
    "scene.world.textures": (True, False),
    "scene.world.sun_glint": (True, False),
    # one camera in both modes (the modes differ only in the water formula): docs/camera.md
    "camera.sensor.noise": (True, True),
    "camera.sensor.bloom_fraction": (BLOOM_FRACTION, BLOOM_FRACTION),
}
#: config setting -> (value for null with fidelity fast, with fidelity reference)
FIDELITY_DEFAULTS: dict[str, tuple[Any, Any]] = {
    "render.light_tree": (False, True),  # fast: one sun, LEDs not sampled; reference: many lights
}
#: config setting -> the experiment-level setting a null stands for
SEED_DEFAULTS: dict[str, str] = {"scene.world.wave_seed": "seed", "scene.world.texture_seed": "seed"}
#: config settings whose null is derived from the rest of the experiment (same in every mode)
DERIVED_DEFAULTS = ("camera.sensor.exposure_s",)  # exposed for the dock's beacons: beacon_exposure_s


def beacon_peak_radiance(exp: Experiment) -> float:
    """The brightest channel of the dock's LEDs (W m^-2 sr^-1): ``I c_k / (pi r^2)`` over every LED
    array's colour and reference colour; 0 without LEDs."""
    from blendgen.physics.light.leds import led_radiance

    peak = 0.0
    for m in exp.scene.dock.markers:
        if m.kind == "led_array":
            for col in (m.color, m.reference_color):
                peak = max(peak, *led_radiance(m.intensity_w_sr, col, m.led_radius_m))
    return peak


def beacon_exposure_s(exp: Experiment) -> float:
    """The exposure (s) that puts the brightest LED channel at 0.9 of the full well
    (``physics.camera.sensor.beacon_exposure_s``; a dock without LEDs: its fixed default)."""
    s = exp.camera.sensor
    return sensor_model.beacon_exposure_s(beacon_peak_radiance(exp), s.full_well_e, s.responsivity_e_per_s)


def mode_default(path: str, image_formation: str) -> Any:
    """The value a null ``path`` (a key of :data:`MODE_DEFAULTS`) takes in ``image_formation``."""
    physical, article = MODE_DEFAULTS[path]
    return physical if image_formation == "physical" else article


def _get(obj, path: str):
    for name in path.split("."):
        obj = getattr(obj, name)
    return obj


def _with(model, path: str, value):
    """A copy of ``model`` with the dotted ``path`` set to ``value`` (nested models copied)."""
    head, _, rest = path.partition(".")
    if not rest:
        return model.model_copy(update={head: value})
    return model.model_copy(update={head: _with(getattr(model, head), rest, value)})


def defaults_for(exp: Experiment) -> dict[str, Any]:
    """{dotted path: value} of every default-by-null setting of ``exp``, resolved."""
    out = {p: mode_default(p, exp.image_formation) for p in MODE_DEFAULTS}
    out |= {p: v[0] if exp.render.fidelity == "fast" else v[1] for p, v in FIDELITY_DEFAULTS.items()}
    out |= {p: _get(exp, src) for p, src in SEED_DEFAULTS.items()}
    if exp.camera.sensor.exposure_s is None:
        out["camera.sensor.exposure_s"] = beacon_exposure_s(exp)
    return out


def value(exp: Experiment, path: str) -> Any:
    """The effective value of one default-by-null setting (dotted ``path``) of ``exp``: the
    config's, else its default (no copy of ``exp``; equal to ``_get(effective(exp), path)``)."""
    v = _get(exp, path)
    return v if v is not None else defaults_for(exp)[path]


def effective(exp: Experiment) -> Experiment:
    """``exp`` with every null of :data:`MODE_DEFAULTS`, :data:`FIDELITY_DEFAULTS`,
    :data:`SEED_DEFAULTS` and :data:`DERIVED_DEFAULTS` replaced by its resolved value (values given in the config are
    kept).
    Idempotent."""
    for path, value in defaults_for(exp).items():
        if _get(exp, path) is None:
            exp = _with(exp, path, value)
    return exp


def effective_sensor(sensor: Sensor, image_formation: str) -> Sensor:
    """A sensor record with its mode-dependent nulls (noise, blooming) resolved."""
    update = {}
    for path in ("camera.sensor.noise", "camera.sensor.bloom_fraction"):
        name = path.rpartition(".")[2]
        if getattr(sensor, name) is None:
            update[name] = mode_default(path, image_formation)
    return sensor.model_copy(update=update) if update else sensor


def as_yaml(exp: Experiment) -> str:
    """The effective config as YAML (the keys in the models' order)."""
    import yaml

    return yaml.safe_dump(effective(exp).model_dump(mode="json"), sort_keys=False)
