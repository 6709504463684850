"""Experiment configuration: YAML -> validated pydantic models.

Every section forbids unknown keys and states its allowed ranges, so a bad config
fails with the file, the key path and the range (:class:`ConfigError`), before
anything is written. Angles are degrees here (the config edge) and radians
everywhere after.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from blendgen.config.bundled import bundled_dir, bundled_names, resolve_config

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]

SAFE_ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
MAX_TRIALS = 1000  # the writer has been run at 1000 trials (6000 frames, ulimit -n 256)
MAX_FRAMES_PER_SEQUENCE = 20_000  # 33 min at 10 fps; the writer has been run at 19991 frames
MAX_FRAMES_TOTAL = 500_000  # per dataset: manifest.json (3 files a frame) stays under 256 MiB


def _no_dotdot(value: str) -> str:
    if ".." in value:
        raise ValueError(f"not a safe name; {SAFE_ID_RULE}")
    return value


SAFE_ID_RULE = (
    "allowed: 1-64 ASCII letters, digits, '_', '.', '-', starting with a letter or digit, "
    "no '..' (it becomes a file or folder name)"
)
SafeId = Annotated[str, Field(pattern=SAFE_ID_PATTERN, description=SAFE_ID_RULE), AfterValidator(_no_dotdot)]
Color = Annotated[list[Annotated[float, Field(ge=0.0, le=1.0)]], Field(min_length=3, max_length=3)]


class ConfigError(Exception):
    """A user error in a config file: message names the file, key path and allowed range."""


class OutputDirError(ConfigError):
    """``-o`` cannot hold a dataset: unwritable, a file, or inside dockbench's source tree."""


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=False, allow_inf_nan=False)


class Pose(Strict):
    """A rigid pose: translation (m) and roll/pitch/yaw (deg, ZYX)."""

    xyz: Vec3 = [0.0, 0.0, 0.0]
    rpy_deg: Vec3 = [0.0, 0.0, 0.0]


class Pool(Strict):
    """Pool-style volume: x in [-length/2, length/2], y in [-width/2, width/2], z in [-depth, 0]."""

    length_m: float = Field(15.0, gt=0.5, le=1000)
    width_m: float = Field(5.0, gt=0.5, le=1000)
    depth_m: float = Field(8.0, gt=0.5, le=1000)
    walls: bool = True
    wall_color: Color = [0.55, 0.62, 0.66]
    floor_color: Color = [0.5, 0.55, 0.55]


class Obstacle(Strict):
    """A large fixed obstacle in world coordinates."""

    kind: Literal["box", "cylinder", "rock"]
    pose: Pose = Pose()
    size_m: Vec3 = Field([1.0, 1.0, 1.0], description="box: x,y,z sides; cylinder: diameter, diameter, height")
    color: Color = [0.35, 0.33, 0.3]

    @model_validator(mode="after")
    def _positive(self):
        if min(self.size_m) <= 0:
            raise ValueError(f"size_m must be > 0 in every axis, got {self.size_m}")
        return self


class LedArray(Strict):
    kind: Literal["led_array"] = "led_array"
    id: SafeId = "led"
    layout: Literal["rectangle", "circle", "custom"] = Field(
        "rectangle",
        description="rectangle: 4 corners; circle: count LEDs evenly on a circle from the top, "
        "clockwise; custom: positions_m",
    )
    count: int = Field(4, ge=4, le=32, description="number of LEDs (rectangle: 4)")
    positions_m: list[Annotated[list[float], Field(min_length=2, max_length=2)]] | None = Field(
        None, description="custom layout: LED centres (x, y) in the marker frame (m), in convex position"
    )
    size_m: float = Field(0.6, gt=0.01, le=5.0, description="overall size l (side or diameter)")
    height_m: float | None = Field(None, gt=0.01, le=5.0, description="rectangle height (default = size)")
    led_radius_m: float = Field(0.04, gt=0.001, le=0.5)
    color: Color = [0.0, 0.85, 0.6]
    reference_color: Color = [1.0, 0.35, 0.0]
    reference_index: int | list[int] = Field(
        0, description="index (or indices) of the reference LED(s), which have reference_color"
    )
    intensity_w_sr: float = Field(
        0.1,
        gt=0.0,
        le=1e3,
        description="on-axis radiant intensity of each LED per unit colour weight (W/sr; channel k emits "
        "intensity_w_sr * color[k]); a flat Lambertian disc of radiance I/(pi r^2) in both "
        "fidelities (physics/light/leds.py). 0.1 = the former strength 20 at r = 0.04 m",
    )
    center_m: Annotated[list[float], Field(min_length=2, max_length=2)] = [0.0, 0.0]

    @model_validator(mode="before")
    @classmethod
    def _old_strength(cls, data):
        """Configs of generator 1.0 gave ``strength`` (radiance per colour weight, W/m^2/sr):
        read as ``intensity_w_sr = strength * pi * led_radius_m^2`` (exact)."""
        if isinstance(data, dict) and "strength" in data:
            if "intensity_w_sr" in data:
                raise ValueError("give intensity_w_sr (W/sr) only: strength is its old radiance form")
            data = dict(data)
            s = data.pop("strength")
            if not isinstance(s, (int, float)) or isinstance(s, bool) or not (0 < s <= 1e5):
                raise ValueError(f"strength (old key, radiance scale) must be a number in (0, 1e5], got {s!r}")
            from blendgen.physics.light.leds import intensity_from_strength

            data["intensity_w_sr"] = intensity_from_strength(s, float(data.get("led_radius_m", 0.04)))
        return data

    @property
    def reference_indices(self) -> list[int]:
        """The reference LEDs' indices, sorted."""
        r = self.reference_index
        return sorted({int(r)} if isinstance(r, int) else {int(i) for i in r})

    @model_validator(mode="after")
    def _layout(self):
        if self.layout == "custom":
            if not self.positions_m:
                raise ValueError("layout 'custom' needs positions_m (>= 4 [x, y] pairs)")
            self.count = len(self.positions_m)
            if not 4 <= self.count <= 32:
                raise ValueError(f"positions_m: need 4..32 LEDs, got {self.count}")
        elif self.positions_m is not None:
            raise ValueError(f"positions_m is only for layout 'custom', not {self.layout!r}")
        elif self.layout == "rectangle" and self.count != 4:
            raise ValueError(f"a rectangle has 4 LEDs, got count {self.count} (use circle or custom)")
        refs = self.reference_indices
        if not refs or refs[0] < 0 or refs[-1] >= self.count or len(refs) >= self.count:
            raise ValueError(
                f"reference_index must name 1..{self.count - 1} LEDs in 0..{self.count - 1}, got {self.reference_index}"
            )
        from blendgen.markers import led_pattern_problem

        problem = led_pattern_problem(self)
        if problem:
            raise ValueError(problem)
        return self


class SquareMarker(Strict):
    kind: Literal["qr", "aruco", "apriltag"]
    id: SafeId
    size_m: float = Field(0.15, gt=0.005, le=5.0, description="side of the code without its quiet zone")
    center_m: Annotated[list[float], Field(min_length=2, max_length=2)] = [0.0, 0.0]
    payload: str | None = Field(None, max_length=200, description="qr: text to encode")
    dictionary: str | None = Field(None, description="aruco/apriltag: OpenCV dictionary name")
    marker_id: int = Field(0, ge=0, le=4095)
    error_correction: Literal["L", "M", "Q", "H"] = Field(
        "M", description="qr: error-correction level (the smallest version that fits the payload is used)"
    )
    quiet_zone_modules: int | None = Field(
        None,
        ge=0,
        le=16,
        description="white margin around the code, in modules/cells "
        "(default: 4 for qr as ISO/IEC 18004 asks, 1 cell for aruco/apriltag)",
    )

    @model_validator(mode="after")
    def _kind_fields(self):
        if self.kind == "qr" and not self.payload:
            raise ValueError("a qr marker needs a non-empty 'payload'")
        if self.quiet_zone_modules is None:
            self.quiet_zone_modules = 4 if self.kind == "qr" else 1
        if self.kind == "qr":
            try:
                import segno

                segno.make_qr(self.payload, error=self.error_correction.lower(), boost_error=False)
            except Exception as exc:  # noqa: BLE001 - segno's DataOverflowError and friends
                raise ValueError(
                    f"payload cannot be encoded as a QR code at level {self.error_correction}: {exc}"
                ) from None
        if self.kind in ("aruco", "apriltag"):
            import cv2

            default = "DICT_4X4_50" if self.kind == "aruco" else "DICT_APRILTAG_36h11"
            self.dictionary = self.dictionary or default
            if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
                raise ValueError(f"unknown OpenCV dictionary {self.dictionary!r} (e.g. DICT_4X4_50)")
            n = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
            if self.marker_id >= n:
                raise ValueError(f"marker_id {self.marker_id} out of range 0..{n - 1} for {self.dictionary}")
        return self


Marker = Annotated[LedArray | SquareMarker, Field(discriminator="kind")]


class Dock(Strict):
    """Docking station: its top ``water_depth_m`` below the surface, face normal along ``facing_deg``."""

    position_xy_m: Annotated[list[float], Field(min_length=2, max_length=2)] = [7.0, 0.0]
    water_depth_m: float = Field(
        1.0,
        ge=0.0,
        le=1000.0,
        description="depth (m) of the dock's top (the highest "
        "point of body and markers) below the water surface; 0: just under it",
    )
    facing_deg: float = Field(180.0, ge=-360, le=360, description="world yaw of the face normal (180 = -x)")
    body_size_m: Vec3 = [1.0, 1.0, 0.4]
    face_color: Color = [0.25, 0.27, 0.28]
    markers: list[Marker] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique_ids(self):
        ids = [m.id for m in self.markers]
        if len(set(ids)) != len(ids):
            raise ValueError(f"marker ids must be unique, got {ids}")
        return self


class WorldLook(Strict):
    """What surrounds the dock (docs/light.md): the water surface seen from below, textured pool
    and dock, caustics. ``null`` switches: on in ``physical`` mode, off in ``article`` mode
    (which keeps the article's flat look). Physics: ``physics/surface/optics.py``."""

    surface: bool | None = Field(
        None, description="water surface seen from below (Snell's window, total internal reflection outside it)"
    )
    caustics: bool | None = Field(None, description="sunlight focused by the surface waves on floor, walls and dock")
    textures: bool | None = Field(None, description="tiled pool, painted/metal dock, sand-and-rock seabed")
    sun_glint: bool | None = Field(
        None,
        description="the sun's disc (0.265 deg radius, irradiance "
        "scene.sun_strength) seen through Snell's window; "
        "needs the surface",
    )
    wind_mps: float = Field(
        1.0,
        ge=0.0,
        le=20.0,
        description="wind speed setting the surface slope (Cox-Munk mean-square slope 0.003 + 5.12e-3 U)",
    )
    wave_seed: int | None = Field(None, ge=0, description="seed of the surface waves; null: the experiment seed")
    texture_seed: int | None = Field(
        None, ge=0, description="seed of texture randomisation (tile colour, grime, rocks); null: the experiment seed"
    )
    tile_size_m: float = Field(0.25, ge=0.02, le=2.0, description="pool tile edge (m)")
    grime: float = Field(0.35, ge=0.0, le=1.0, description="strength of the dirt on tiles and dock (0: clean)")
    seabed_depth_m: float = Field(12.0, gt=0.5, le=1000.0, description="open water: seabed depth below the surface")


class Scene(Strict):
    template: str | None = None
    kind: Literal["pool", "open_water"] = "pool"
    pool: Pool = Pool()
    dock: Dock = Dock()
    obstacles: list[Obstacle] = Field(default_factory=list)
    sun_elevation_deg: float = Field(
        60.0,
        gt=0.0,
        le=90.0,
        description="elevation of the sunlight's direction in water, after "
        "refraction at the surface (deg; above 41.4 when the "
        "surface or caustics are on: Snell's window)",
    )
    sun_azimuth_deg: float = Field(180.0, ge=-360, le=360)
    sun_strength: float = Field(3.0, ge=0.0, le=1000.0, description="sun irradiance at the surface (W/m^2)")
    fill_strength: float = Field(
        0.0,
        ge=0.0,
        le=1000.0,
        description="horizontal fill light (W/m^2); > 0 adds light-selection "
        "noise at few samples (Cycles samples one light per path)",
    )
    sky_fraction: float | None = Field(
        None,
        ge=0.0,
        le=10.0,
        description="diffuse sky irradiance on a horizontal surface as a fraction of the sun's; "
        "null: 0.25 in physical mode, 0 in article mode",
    )
    ambient: bool | None = Field(
        None,
        description="light of the water's diffuse light field on every surface (no black shadows); "
        "null: on in physical mode, off in article mode",
    )
    world: WorldLook = WorldLook()


class AutoExposureConfig(Strict):
    """Auto-exposure (``physics/camera/sensor.AutoExposure``): meter the previous frame's brightest
    channel per pixel (``mean`` or a ``percentile``), aim it at ``target`` x full well, follow
    with time constant ``time_constant_s``, clamp to the exposure limits."""

    metering: Literal["mean", "percentile"] = Field(
        "percentile",
        description="mean: average metering (target ~0.18); percentile: highlight "
        "metering (99.9 and target 0.9 keep small LEDs just below saturation)",
    )
    percentile: float = Field(99.9, ge=0.0, le=100.0, description="percentile metered (percentile metering)")
    target: float = Field(0.9, gt=0.0, le=1.0, description="metered value as a share of the full well")
    min_exposure_s: float = Field(1e-5, gt=0.0, le=1.0, description="shortest exposure (s)")
    max_exposure_s: float = Field(0.05, gt=0.0, le=1.0, description="longest exposure (s)")
    time_constant_s: float = Field(0.3, ge=0.0, le=60.0, description="AE loop time constant (s); 0: at once")

    @model_validator(mode="after")
    def _limits(self):
        if self.min_exposure_s > self.max_exposure_s:
            raise ValueError(f"min_exposure_s {self.min_exposure_s} > max_exposure_s {self.max_exposure_s}")
        return self


class Sensor(Strict):
    """The camera's sensor (EMVA 1288 photon-transfer model): radiance -> electrons over the
    exposure (plus dark current) -> blooming, shot and read noise -> saturation at the full well ->
    digital numbers with system gain ``K = gain * 255 / full_well_e`` DN/e- -> response curve -> 8 bits.
    The same sensor runs after the water in both image-formation modes.

    Defaults: a Sony IMX264 pixel (3.45 um, Pregius 2nd generation) as the EMVA 1288 summaries of
    IMX264 cameras give it (Basler ace acA2440-20gm; Teledyne FLIR Blackfly S BFS-U3-50S5M), rounded:
    QE 70 % near 530 nm, temporal dark noise 2.3 e-, saturation capacity 10.5 ke-, dark current ~3 e-/s;
    behind an f/2.8 lens that is 2.23e6 e-/s per W m^-2 sr^-1 (``physics/camera/sensor.responsivity_e_per_s``).
    docs/camera.md has the derivations."""

    exposure_s: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="exposure time (s); null: exposed for the dock's beacons, the brightest LED channel "
        "(radiance I c_k / (pi r^2), the same at every range in clear water) at 0.9 of the full "
        "well (physics/camera/sensor.beacon_exposure_s; 0.2 ms for the default LEDs); without LEDs "
        "4000 e- per unit radiance (the former 4 ms at 1e6 e-/s)",
    )
    responsivity_e_per_s: float = Field(
        2.23e6,
        gt=0.0,
        le=1e12,
        description="electrons per second per unit linear radiance of the render "
        "(W m^-2 sr^-1): QE x pixel area x pi/(4 N^2) / photon energy; "
        "2.23e6 = IMX264 (QE .70, 3.45 um) at f/2.8, 530 nm",
    )
    full_well_e: float = Field(
        10500.0, ge=100.0, le=1e7, description="saturation capacity (electrons); IMX264: 10.5 ke-"
    )
    read_noise_e: float = Field(
        2.3, ge=0.0, le=1000.0, description="temporal dark noise (electrons rms); IMX264: 2.3 e-"
    )
    dark_current_e_per_s: float = Field(
        3.0,
        ge=0.0,
        le=1e6,
        description="dark current (e-/s); IMX264 cameras: a few e-/s at room temperature (negligible at ms exposures)",
    )
    gain: float = Field(1.0, gt=0.0, le=1000.0, description="analog gain (1: the full well is 255 DN)")
    noise: bool | None = Field(
        None, description="shot, dark-current and read noise; null: on (both modes; the article's noise_std adds to it)"
    )
    response: Literal["srgb", "linear"] = Field("srgb", description="response curve to 8 bits")
    bloom_fraction: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="share of the charge above the full well that spills into neighbouring pixels (0: "
        "perfect anti-blooming drain); null: 0.05 in both modes (saturated LEDs spread "
        "their own colour around the clipped core)",
    )
    bloom_sigma_px: float = Field(2.0, gt=0.0, le=50.0, description="spread of the spilled charge (px)")
    motion_blur: bool = Field(False, description="blur by the camera's motion over the exposure")
    auto_exposure: AutoExposureConfig | None = Field(
        None,
        description="exposure control between frames (null: fixed exposure_s, the first frame's "
        "exposure when on); each frame's exposure is recorded in its frame record",
    )


class Lens(Strict):
    """Thin lens (docs/sensor.md: defocus of small obstacles). The pixel pitch follows from
    ``focal_length_mm`` and the focal length in pixels (hfov, width)."""

    focal_length_mm: float = Field(4.0, gt=0.1, le=500.0, description="focal length (mm)")
    f_number: float = Field(2.8, ge=0.5, le=64.0, description="f-number N (aperture diameter f/N)")
    focus_m: float = Field(5.0, gt=0.05, le=1000.0, description="focus distance (m), > focal length")

    @model_validator(mode="after")
    def _focus_beyond_focal_length(self):
        if self.focus_m <= self.focal_length_mm * 1e-3:
            raise ValueError(f"focus_m ({self.focus_m}) must exceed the focal length ({self.focal_length_mm} mm)")
        return self


class Camera(Strict):
    width: int = Field(640, ge=16, le=8192)
    height: int = Field(480, ge=16, le=8192)
    hfov_deg: float = Field(60.0, gt=1.0, lt=179.0)
    fps: float = Field(10.0, gt=0.0, le=1000.0)
    latency_s: float = Field(0.0, ge=0.0, le=10.0)
    T_body_cam: Pose = Pose(xyz=[0.65, 0.0, 0.0])
    distortion: Annotated[list[float], Field(min_length=5, max_length=5)] | None = None
    noise_std: float = Field(
        0.0,
        ge=0.0,
        le=256.0,
        description="the article's Gaussian noise: std in 8-bit codes, added after the "
        "sensor's response curve on top of its shot and read noise (in a "
        "linear response: an extra read noise of noise_std / K electrons)",
    )
    sensor: Sensor = Sensor()
    lens: Lens | None = Field(None, description="thin lens for particle defocus; null: pinhole (sharp)")


class Lamp(Strict):
    """A lamp on the vehicle (docs/LAMP.md): a spot of radiant flux ``power_w`` spread over a cone.

    Mounted at ``offset_m`` in the camera frame (OpenCV: x right, y down, z forward), aimed
    ``yaw_deg`` right and ``pitch_deg`` down of the optical axis. Physics: ``physics/light/sources.py``."""

    id: SafeId = "lamp"
    offset_m: Vec3 = Field([0.0, 0.3, 0.0], description="position in the camera frame (m)")
    yaw_deg: float = Field(0.0, ge=-90.0, le=90.0, description="aim right of the optical axis")
    pitch_deg: float = Field(0.0, ge=-90.0, le=90.0, description="aim below the optical axis")
    half_angle_deg: float = Field(30.0, gt=1.0, le=90.0, description="cone half-angle")
    edge_deg: float = Field(5.0, ge=0.0, le=45.0, description="soft edge inside the cone")
    power_w: float = Field(10.0, gt=0.0, le=1e4, description="radiant flux into the cone (W)")
    color: Color = [1.0, 1.0, 1.0]


class Vehicle(Strict):
    """What the vehicle carries besides the camera."""

    lamps: list[Lamp] = Field(default_factory=list, max_length=8)
    lamp_forward_kept: float = Field(
        0.85,
        ge=0.0,
        le=1.0,
        description="fast lamp model: share F of scattered lamp light a smooth light field keeps "
        "(attenuation c - F b; 0 = single scattering as the 0-bounce reference renders; "
        "0.85 fitted to Cycles with 32 volume bounces, physics/light/lamp_water.py)",
    )
    lamp_shadows: bool = Field(
        True,
        description="fast lamp model: screen-space shadows of the lamps on surfaces (a march along "
        "each lit point's segment to the lamp in the range pass, physics/light/lamp_shadow.py); "
        "false: every surface sees the lamps (the reference always has shadows)",
    )


class Render(Strict):
    fidelity: Literal["fast", "reference"] = "fast"
    samples: int = Field(4, ge=1, le=65536)
    reference_samples: int = Field(64, ge=1, le=65536)
    threads: int = Field(0, ge=0, le=256, description="Cycles threads per worker; 0 = cores / workers")
    diffuse_bounces: int = Field(
        0, ge=0, le=16, description="Cycles diffuse bounces (interreflection; noisy at few samples)"
    )
    volume_bounces: int = Field(
        32,
        ge=0,
        le=128,
        description="reference fidelity: Cycles volume bounces in the water medium "
        "(0 = single scattering). Default 32: converged, the reference "
        "judges the fast path with the multiply scattered veil and glow "
        "(32 vs 64 bounces within 1 %: tests/test_reference_convergence.py); "
        "lower it for speed",
    )
    write_depth: bool = True
    write_index: bool = True
    roi: bool = Field(True, description="fast fidelity: full samples only in the dock's image region")
    background_scale: float = Field(
        0.35,
        gt=0.05,
        le=1.0,
        description="resolution factor outside the ROI. 0.35: 24 % less render CPU than 0.5; physical "
        "turbidity trial at 640x480: every P_succ equal, E_rel equal but one (qr, mild: 0.96 -> 0.98 %), "
        "marker region <= 0.37 DN mean (`bench render-settings`, docs/evidence/render_settings.txt)",
    )
    background_samples: int = Field(1, ge=1, le=65536)
    roi_regions: Literal["dock", "markers", "codes"] = Field(
        "codes",
        description="fast fidelity: where `samples` go: dock (one box around the dock); markers "
        "(a box per marker plate and per LED disc); codes (a box per code square "
        "without its uniform quiet zone and per LED disc; `bench render-settings`)",
    )
    roi_max_boxes: int = Field(
        6,
        ge=1,
        le=64,
        description="roi_regions markers: at most this many ROI render calls per frame (nearest boxes merged)",
    )
    roi_max_fraction: float = Field(
        0.9,
        gt=0.0,
        le=1.0,
        description="fast fidelity: ROIs covering more than this share of the "
        "image render the whole frame at `samples`",
    )
    light_tree: bool | None = Field(
        None,
        description="Cycles light tree; null: off in fast fidelity (one sun, LEDs not sampled: same "
        "image, fewer CPU-s), on in reference fidelity (sampled LEDs and lamps)",
    )
    max_distance_m: float | None = Field(
        10.0,
        gt=0.0,
        le=1e4,
        description="frames with d_true beyond this are not rendered "
        "(evaluation counts d_true <= 10 m); null renders all",
    )


Coef = Annotated[float, Field(ge=0.0, le=5.0)]
Coef3 = Coef | Annotated[list[Coef], Field(min_length=3, max_length=3)]
Unit = Annotated[float, Field(ge=0.0, le=1.0)]
Unit3 = Unit | Annotated[list[Unit], Field(min_length=3, max_length=3)]
Veil = Annotated[float, Field(ge=0.0, le=10.0)]
Veil3 = Veil | Annotated[list[Veil], Field(min_length=3, max_length=3)]

#: The two image-formation modes (docs/water.md): ``physical`` (what water and light do) and
#: ``article`` (the article's formulas: blend toward the water colour with
#: ``w = 1 - exp(-beta d)``, every pixel scaled by ``exp(-k depth)``).
ImageFormation = Literal["physical", "article"]


class Water(Strict):
    """Water optics of a condition: a named preset plus typed overrides.

    A number for a per-channel coefficient means the same value in R, G and B.
    Coefficients are 1/m in [0, 5]; ``water_color`` linear RGB in [0, 1]; ``B_inf``
    veiling light per unit downwelling irradiance in [0, 10]. The article's shorthand
    ``beta`` (optional ``albedo``) applies to the article presets only."""

    preset: str = Field("clear", description="clear | mild | moderate | jerlov_<I..9C>")
    name: str | None = Field(None, max_length=64)
    provenance: str | None = Field(None, max_length=500)
    beta: Coef3 | None = Field(None, description="article: beam attenuation c = beta (1/m)")
    albedo: Unit3 | None = Field(None, description="article: single-scattering albedo b/c")
    water_color: Unit3 | None = Field(None, description="veiling-light colour (linear RGB)")
    k: Coef3 | None = Field(None, description="depth-light coefficient (1/m), the article's k")
    Kd: Coef3 | None = Field(None, description="diffuse attenuation of downwelling light (1/m)")
    sigma_a: Coef3 | None = None
    sigma_s: Coef3 | None = None
    B_inf: Veil3 | None = None
    g: float | None = Field(None, gt=-1.0, lt=1.0, description="Henyey-Greenstein mean cosine")
    phase: Literal["hg", "ff"] | None = None
    ff_ior: float | None = Field(None, gt=1.0, le=1.5)
    ff_backscatter: float | None = Field(None, gt=0.0, lt=0.5)
    calibrated: bool = Field(
        False,
        description="fast fidelity: veiling light fitted to reference renders "
        "(blendgen/data/water_calibration.json) instead of the "
        "light-field estimate",
    )
    blur: bool = Field(False, description="fast fidelity: range-dependent forward-scatter blur")
    secchi_m: float | None = Field(
        None,
        gt=0.0,
        le=1000.0,
        description="a Secchi depth reading (m): the water "
        "between the Jerlov types of that clarity (physics/water/turbidity.py)",
    )
    ntu: float | None = Field(
        None,
        gt=0.0,
        le=1e4,
        description="a nephelometric turbidity reading (NTU): "
        "the water between the Jerlov types of that scattering (physics/water/turbidity.py)",
    )
    glow: bool = Field(
        True,
        description="fast fidelity: forward-scattered glow around the LEDs (small-angle "
        "multiple scattering from sigma_s and g, physics/water/optics.py), in both "
        "modes (article: sigma_s = albedo * beta); false: none",
    )

    @field_validator("preset", mode="before")
    @classmethod
    def _known_preset(cls, v):
        from blendgen.physics.water.presets import preset_key

        return preset_key(v)

    @model_validator(mode="after")
    def _consistent(self):
        from blendgen.physics.water.presets import ARTICLE_BETAS

        for a, b in (("water_color", "B_inf"), ("k", "Kd"), ("beta", "sigma_a"), ("beta", "sigma_s")):
            if getattr(self, a) is not None and getattr(self, b) is not None:
                raise ValueError(f"give either {a!r} or {b!r}, not both")
        article = self.preset in ARTICLE_BETAS
        if self.beta is not None and not article:
            raise ValueError(
                f"'beta' applies to the article presets {tuple(ARTICLE_BETAS)}, not "
                f"{self.preset!r}; give sigma_a/sigma_s instead"
            )
        if self.albedo is not None and not article:
            raise ValueError("'albedo' only applies with 'beta' or an article preset")
        return self._reading()

    def _reading(self):
        """A turbidity reading (``secchi_m`` or ``ntu``) names the water itself: its preset
        becomes the clearer ladder type it lies above (recorded), its range is checked."""
        given = [k for k in ("secchi_m", "ntu") if getattr(self, k) is not None]
        if not given:
            return self
        if len(given) > 1 or "preset" in self.model_fields_set or self.beta is not None:
            raise ValueError("give one of preset, secchi_m or ntu (a reading names the water)")
        from blendgen.physics.water import turbidity

        kind = given[0]
        turbidity.water_from_reading(kind, getattr(self, kind))  # ValueError: the allowed range
        self.preset = f"jerlov_{turbidity.ladder_type(kind, getattr(self, kind))}"
        return self

    @property
    def is_bare(self) -> bool:
        """True when no coefficient is overridden (only the preset and the fast-model switches)."""
        return all(
            getattr(self, f) is None
            for f in type(self).model_fields
            if f not in ("preset", "calibrated", "blur", "glow")
        )


class LinearTrajectory(Strict):
    kind: Literal["linear"] = "linear"
    id: SafeId = "linear"
    start_range_m: float = Field(12.0, gt=0.0, le=1000.0)
    end_range_m: float = Field(0.5, ge=0.0, le=1000.0)
    speed_mps: float = Field(1.0, gt=0.0, le=20.0)
    lateral_m: float = Field(0.0, ge=-100, le=100)
    vertical_m: float = Field(0.0, ge=-100, le=100)

    @model_validator(mode="after")
    def _order(self):
        if self.end_range_m >= self.start_range_m:
            raise ValueError(f"end_range_m ({self.end_range_m}) must be < start_range_m ({self.start_range_m})")
        return self


class CircleTrajectory(Strict):
    kind: Literal["circle"] = "circle"
    id: SafeId = "circle"
    radius_m: float = Field(3.0, gt=0.05, le=1000.0)
    height_m: float = Field(0.0, ge=-100, le=100)
    start_deg: float = Field(-45.0, ge=-360, le=360, description="angle from the dock normal")
    end_deg: float = Field(45.0, ge=-360, le=360)
    speed_mps: float = Field(0.5, gt=0.0, le=20.0)


class StartRanges(Strict):
    """Random initial positions of docking trials, relative to the dock (m, deg);
    a pair is [lo, hi], a single number a means [-a, a]."""

    range_m: Annotated[list[float], Field(min_length=2, max_length=2)] = [6.0, 12.0]
    lateral_m: float = Field(1.5, ge=0.0, le=100.0)
    vertical_m: float = Field(0.5, ge=0.0, le=100.0)
    heading_error_deg: float = Field(15.0, ge=0.0, le=90.0)

    @model_validator(mode="after")
    def _order(self):
        lo, hi = self.range_m
        if not 0.5 <= lo <= hi <= 1000:
            raise ValueError(f"range_m must be [lo, hi] with 0.5 <= lo <= hi <= 1000, got {self.range_m}")
        return self


class CaptureLimits(Strict):
    """When a closed-loop trial (``dockbench dock``) counts as docked: the nose crosses the dock's
    entry plane within ``radius_m`` of the face centre with |heading error| and |lateral speed|
    within limits. Entry offset, heading and lateral speed are the critical docking parameters
    measured by Martin et al., "Characterizing the critical parameters for docking unmanned
    underwater vehicles", OCEANS 2016; the 15 deg / 0.25 m/s defaults are round values for a
    funnel-less 1 m face, not a measured dock's: set them from your dock."""

    radius_m: float | None = Field(
        None,
        gt=0.0,
        le=10.0,
        description="capture radius (m); none: the dock "
        "face's inscribed circle minus the hull radius (0.40 m for the 1 m face)",
    )
    max_heading_deg: float = Field(15.0, gt=0.0, le=90.0, description="largest |heading error| at entry (deg)")
    max_lateral_speed_mps: float = Field(
        0.25, gt=0.0, le=3.0, description="largest |speed across the dock axis| at entry (m/s)"
    )


class DockingTrajectory(Strict):
    """Closed-loop docking trial of the 6-DOF vehicle (blendgen.vehicle.docking) from a seeded random start."""

    kind: Literal["docking"] = "docking"
    id: SafeId = "docking"
    start: StartRanges = StartRanges()
    stop_distance_m: float = Field(0.5, gt=0.0, le=100.0)
    max_time_s: float = Field(120.0, gt=0.0, le=3600.0)
    cruise_speed_mps: float = Field(0.5, gt=0.0, le=3.0)
    final_speed_mps: float = Field(0.2, gt=0.0, le=3.0)
    capture: CaptureLimits = Field(
        default_factory=CaptureLimits, description="docking success limits (closed loop only)"
    )


Trajectory = Annotated[LinearTrajectory | CircleTrajectory | DockingTrajectory, Field(discriminator="kind")]


class Fluid(Strict):
    """Water as a fluid: it acts on the vehicle (buoyancy, drag, current)."""

    density_kg_m3: float = Field(1025.0, ge=900.0, le=1200.0, description="998.2 fresh, 1025 sea")
    viscosity_pa_s: float = Field(1.3e-3, gt=0.0, le=0.1, description="1.002e-3 fresh, 1.3e-3 sea (recorded)")
    current_mps: Vec3 = Field([0.0, 0.0, 0.0], description="background flow in the world frame")

    @model_validator(mode="after")
    def _speed(self):
        speed = sum(c * c for c in self.current_mps) ** 0.5
        if speed > 2.0:
            raise ValueError(f"current speed must be <= 2 m/s, got {speed:.3g}")
        return self


class Occlusion(Strict):
    """Small obstacles / marine snow (the article's section 2.2.3, made physical: docs/particles.md):
    N_total particles in a region of volume V_env (default: the pool, 600 m^3 for 15x5x8),
    radii from ``size_dist`` in [r_min, r_max], drifting with the current plus Gaussian
    noise, lit by the light field (physics/particles/optics.py)."""

    n_total: float = Field(600, ge=0.0, le=2e7)
    count_dist: Literal["poisson", "uniform", "fixed"] = "poisson"
    n_max: int | None = Field(None, ge=0, le=20_000_000)
    size_dist: Literal["power_law", "uniform"] = Field(
        "power_law",
        description="power_law: marine-snow number spectrum dN/dr ~ r^-size_slope (Stemmann & "
        "Boss 2012); uniform: the article's radius uniform in [r_min_m, r_max_m]",
    )
    size_slope: float = Field(3.5, ge=0.0, le=6.0, description="power-law slope xi of dN/dr ~ r^-xi")
    r_min_m: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="smallest radius (m); default 0.00025 for power_law, 0.005 for uniform (the article)",
    )
    r_max_m: float | None = Field(
        None, gt=0.0, le=1.0, description="largest radius (m); default 0.015 for power_law, 0.02 for uniform"
    )
    albedo: float = Field(0.3, ge=0.0, le=1.0, description="share of the geometric cross-section scattered")
    forward_fraction: float = Field(
        0.5,
        ge=0.0,
        le=1.0,
        description="share of the scattered light in the forward HG lobe (the rest: Lambertian-sphere reflection)",
    )
    forward_g: float = Field(0.9, ge=0.0, lt=1.0, description="HG asymmetry of the forward lobe")
    drift_sigma_m: float = Field(0.002, ge=0.0, le=1.0, description="per-frame Gaussian step std")
    mode: Literal["backscatter", "silhouette", "lit"] = Field(
        "lit",
        description="lit: radiance from the light field (ambient at depth, lamps, LEDs); "
        "backscatter / silhouette: the former constant bright / dark colour",
    )
    geometry: Literal["image", "blender"] = Field(
        "image",
        description="image: depth-tested blobs drawn on the clean render (fast, shared renders); "
        "blender: the same particles as instanced spheres in the scene (validation)",
    )
    region_min: Vec3 | None = None
    region_max: Vec3 | None = None

    @model_validator(mode="after")
    def _ranges(self):
        if self.r_min_m is None:
            self.r_min_m = 0.00025 if self.size_dist == "power_law" else 0.005
        if self.r_max_m is None:
            self.r_max_m = 0.015 if self.size_dist == "power_law" else 0.02
        if self.r_min_m > self.r_max_m:
            raise ValueError(f"r_min_m ({self.r_min_m}) must be <= r_max_m ({self.r_max_m})")
        if self.n_max is not None and self.count_dist != "uniform" and self.n_total > self.n_max:
            raise ValueError(f"n_total ({self.n_total:g}) must be <= n_max ({self.n_max})")
        if (self.region_min is None) != (self.region_max is None):
            raise ValueError("give both region_min and region_max, or neither")
        if self.region_min is not None and not all(a < b for a, b in zip(self.region_min, self.region_max)):
            raise ValueError(f"region_min {self.region_min} must be < region_max {self.region_max} on every axis")
        return self


class Condition(Strict):
    """One experimental condition: a label and what it changes. Water, light depth and
    occlusion are image-space (the clean render is shared); fluid changes the motion."""

    label: SafeId
    water: Water | None = None
    dock_water_depth_m: float | None = Field(
        None,
        ge=0.0,
        le=1000.0,
        description="depth (m) of the dock's top below the surface in this condition (moves the surface)",
    )
    occlusion: Occlusion | None = None
    fluid: Fluid | None = None


class Experiment(Strict):
    """The whole config file."""

    name: SafeId
    image_formation: ImageFormation = Field("physical", description="physical (default) or the article's formulas")
    version: str = Field("0.1.0", pattern=r"^\d+\.\d+\.\d+$")
    seed: int = Field(0, ge=0, le=2**32 - 1)
    scene: Scene = Scene()
    camera: Camera = Camera()
    vehicle: Vehicle = Vehicle()
    render: Render = Render()
    water: Water = Water()
    fluid: Fluid = Fluid()
    occlusion: Occlusion | None = None
    trajectories: list[Trajectory] = Field(min_length=1)
    conditions: list[Condition] = Field(default_factory=lambda: [Condition(label="default")])
    trials: int = Field(1, ge=1, le=MAX_TRIALS)
    d_min_rel_m: float = Field(0.2, gt=0.0, le=10.0, description="e_rel is not computed below this d_true")

    @model_validator(mode="after")
    def _unique(self):
        for what, ids in (
            ("trajectory", [t.id for t in self.trajectories]),
            ("condition", [c.label for c in self.conditions]),
        ):
            if len(set(ids)) != len(ids):
                raise ValueError(f"{what} ids must be unique, got {ids}")
        return self

    @model_validator(mode="after")
    def _frame_budget(self):
        """Refuse datasets larger than the writer has been run at (frames per sequence and
        in total; a docking trial is counted at its ``max_time_s``)."""
        total = 0
        for i, t in enumerate(self.trajectories):
            n = max_frames(t, self.camera.fps, self.camera.latency_s)
            if n > MAX_FRAMES_PER_SEQUENCE:
                raise ValueError(
                    f"trajectories.{i} ({t.id}) gives {n:.3g} frames at {self.camera.fps:g} fps; "
                    f"allowed: at most {MAX_FRAMES_PER_SEQUENCE} frames per sequence "
                    "(raise speed_mps or lower camera.fps / max_time_s)"
                )
            total += n * self.trials * len(self.conditions)
        if total > MAX_FRAMES_TOTAL:
            raise ValueError(
                f"trials x conditions x trajectories give {total:.3g} frames; allowed: at most "
                f"{MAX_FRAMES_TOTAL} frames per dataset"
            )
        return self


def max_frames(traj, fps: float, latency_s: float = 0.0) -> float:
    """Upper bound of the frames one sequence of ``traj`` has at ``fps`` (Hz), as
    blendgen.vehicle.trajectories.frame_times counts them (a docking trial at max_time_s)."""
    import math

    if traj.kind == "linear":
        duration = (traj.start_range_m - traj.end_range_m) / traj.speed_mps
    elif traj.kind == "circle":
        duration = abs(math.radians(traj.end_deg - traj.start_deg)) * traj.radius_m / traj.speed_mps
    else:
        duration = traj.max_time_s
    return math.floor((duration + latency_s) * fps) + 1.0


# discriminator values pydantic puts in error locations (trajectories.0.linear.id -> trajectories.0.id)
_UNION_TAGS = {"linear", "circle", "docking", "led_array", "qr", "aruco", "apriltag"}


def _deep_merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


MAX_CONFIG_BYTES = 1 << 20  # a config is a few kB; 1 MiB leaves room for long lists
MAX_YAML_DEPTH = 64  # the deepest section of a config is 6 levels
MAX_YAML_NODES = 200_000  # nodes after expanding aliases (guards alias bombs)


class _YamlLimit(Exception):
    """A structural limit of a config file was exceeded (message without the path)."""


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader that refuses duplicate keys (YAML 1.2 forbids them)."""

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            try:
                if key in seen:
                    raise _YamlLimit(
                        f"line {line}: duplicate key {key!r} (first at line {seen[key]}); "
                        "each key may appear once per section"
                    )
                seen[key] = line
            except TypeError:  # unhashable key: the schema reports it
                continue
        return super().construct_mapping(node, deep)


def _check_yaml_structure(text: str) -> None:
    """Walk the YAML events (iteratively, no recursion): refuse nesting deeper than
    MAX_YAML_DEPTH and more than MAX_YAML_NODES nodes once aliases are expanded."""
    sizes: dict[str, int] = {}
    stack: list[list] = [[0, None]]  # [expanded node count, anchor] per open collection
    for ev in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            stack.append([0, ev.anchor])
            if len(stack) - 1 > MAX_YAML_DEPTH:
                raise _YamlLimit(f"line {ev.start_mark.line + 1}: nested deeper than {MAX_YAML_DEPTH} levels")
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            n, anchor = stack.pop()
            if anchor:
                sizes[anchor] = n + 1
            stack[-1][0] += n + 1
        elif isinstance(ev, yaml.ScalarEvent):
            stack[-1][0] += 1
            if ev.anchor:
                sizes[ev.anchor] = 1
        elif isinstance(ev, yaml.AliasEvent):
            stack[-1][0] += sizes.get(ev.anchor, 1)
        if stack[-1][0] > MAX_YAML_NODES:
            raise _YamlLimit(
                f"line {ev.start_mark.line + 1}: more than {MAX_YAML_NODES} values once "
                "aliases are expanded (alias bomb?)"
            )


def _read_config_text(path: Path) -> str:
    """The file as UTF-8 text, at most MAX_CONFIG_BYTES; ConfigError otherwise."""
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_CONFIG_BYTES + 1)
    except OSError as e:
        raise ConfigError(f"{path}: cannot read config ({e.strerror})") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{path}: config larger than {MAX_CONFIG_BYTES >> 20} MiB; allowed: up to "
            f"{MAX_CONFIG_BYTES >> 20} MiB of YAML"
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise ConfigError(
            f"{path}: line {line}: byte 0x{data[e.start]:02x} is not UTF-8; a config must be UTF-8 text"
        ) from None


def _read_yaml(path: Path) -> Any:
    """Parse a config or template file safely: size, encoding, depth, alias expansion and
    duplicate keys are checked; every problem is a one-line :class:`ConfigError`."""
    text = _read_config_text(path)
    try:
        _check_yaml_structure(text)
        return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass
    except _YamlLimit as e:
        raise ConfigError(f"{path}: {e}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ConfigError(f"{path}:{where} YAML syntax error: {getattr(e, 'problem', e)}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply (allowed: {MAX_YAML_DEPTH} levels)") from None


def _apply_template(raw: dict, path: Path) -> dict:
    scene = raw.get("scene") or {}
    name = scene.get("template") if isinstance(scene, dict) else None
    if not name:
        return raw
    tpath = (path.parent / name) if str(name).endswith((".yaml", ".yml")) else bundled_dir("templates") / f"{name}.yaml"
    if not tpath.exists():
        known = bundled_names("templates")
        raise ConfigError(f"{path}: scene.template: no template {name!r} (known: {', '.join(known)})")
    tpl = _read_yaml(tpath)
    if not isinstance(tpl, dict):
        raise ConfigError(f"{tpath}: a template must be a mapping")
    return {**raw, "scene": _deep_merge(tpl, scene)}


def format_validation_error(path: Path, err: ValidationError) -> str:
    """One line per problem: ``file: key.path: message (got value)``."""
    lines = []
    for e in err.errors():
        parts = [
            str(p)
            for i, p in enumerate(e["loc"])
            if not str(p).startswith(("function-after", "tagged-union"))
            and not (p in _UNION_TAGS and i > 0 and isinstance(e["loc"][i - 1], int))
        ]
        loc = ".".join(parts)
        if e["type"] == "string_pattern_mismatch" and e.get("ctx", {}).get("pattern") == SAFE_ID_PATTERN:
            e = {**e, "msg": f"not a safe name; {SAFE_ID_RULE}"}
        got = e.get("input")
        got_s = "" if isinstance(got, (dict, list)) or got is None else f" (got {got!r})"
        msg = e["msg"].removeprefix("Value error, ")
        lines.append(f"{path}: {loc or '<root>'}: {msg}{got_s}")
    return "\n".join(lines)


def load_experiment(path: str | Path) -> Experiment:
    """Read, template-merge and validate a config file (a path, or a bundled config's name such
    as ``quickstart``); raise ConfigError on any user error."""
    path = resolve_config(path)
    if not path.exists():
        raise ConfigError(
            f"{path}: cannot read config (no such file); bundled configs (give the name): "
            f"{', '.join(bundled_names('configs'))} (dockbench configs)"
        )
    raw = _read_yaml(path)
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: the config must be a YAML mapping, got {type(raw).__name__}")
    raw = _apply_template(raw, path)
    try:
        exp = Experiment.model_validate(raw)
    except ValidationError as e:
        raise ConfigError(format_validation_error(path, e)) from None
    return exp


def article_grey_spec(name: str) -> Water:
    """The water section of an article level's own grey water (``beta`` given), which the
    ``physical`` mode keeps as is, with a Jerlov Kd (``physics.water.optics.water_for_mode``)."""
    from blendgen.physics.water import presets as water_presets

    return Water(preset=name, beta=water_presets.ARTICLE_BETAS[name])
