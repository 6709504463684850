"""What crosses to the renderer, typed: the scene, the render settings, the planned frames and
the markers of a render job (:class:`blendgen.pipeline.plan.JobRecord`), and of the closed
loop's warm render server (:mod:`blendgen.blender.serve`).

The planner builds these records as plain data (:func:`blendgen.pipeline.plan.scene_description`,
:func:`~blendgen.pipeline.plan.render_settings`, ``plan._frames``); the job record validates them
when it is made and again when a worker reads the job file, so a misspelt or missing key is a
validation error before Blender starts. Every model refuses unknown keys. Keys that the planner
adds only in some cases (``lamps``, ``water_volume``, ``water_surface``, ``particles`` of the
scene; ``roi``/``rois``/``blur_px`` of a frame; ``normal_pass``/``sun_pass`` of the render
settings; ``texture`` of a marker) are written only when they were given, so a job file keeps
the bytes it had as plain data (field order = the planner's key order).

Units: metres, seconds, radians unless a name says otherwise; colours linear RGB; poses 4x4
row-major lists (OpenCV camera: x right, y down, z forward).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, model_serializer

from blendgen.config.models import Lamp, Occlusion, Pool, Vec3

Matrix = list[list[float]]


class Record(BaseModel):
    """Strict plain data; the fields named in ``OPTIONAL_KEYS`` are dumped only when given."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset()

    @model_serializer(mode="wrap")
    def _given_keys_only(self, handler):
        data = handler(self)
        if not self.OPTIONAL_KEYS:
            return data
        return {k: v for k, v in data.items() if k not in self.OPTIONAL_KEYS or k in self.model_fields_set}


# -- markers: the manifest entry plus what the renderer needs -----------------------------
class _MarkerBase(Record):
    """Fields in the manifest's key order: id, kind, T_dock_marker, keypoints, then the kind's."""

    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset({"texture"})


class LedArrayMarker(_MarkerBase):
    id: str
    kind: Literal["led_array"]
    T_dock_marker: Matrix
    keypoints: Matrix
    led_radius_m: float
    colors: list[list[float]]
    reference_index: int
    reference_indices: list[int]
    layout: str
    size_m: float
    intensity_w_sr: float
    radiance: list[list[float]] = Field(description="W/m^2/sr per LED (3 channels)")
    object_index: int
    texture: str | None = None


class QrMarker(_MarkerBase):
    id: str
    kind: Literal["qr"]
    T_dock_marker: Matrix
    keypoints: Matrix
    size_m: float
    payload: str
    qr_version: int
    error_correction: str
    modules: int
    module_size_m: float
    quiet_zone_modules: int
    object_index: int
    plate_size_m: float
    texture: str | None = None


class SquareMarker(_MarkerBase):
    id: str
    kind: Literal["aruco", "apriltag"]
    T_dock_marker: Matrix
    keypoints: Matrix
    size_m: float
    dictionary: str
    marker_id: int
    quiet_zone_modules: int
    object_index: int
    plate_size_m: float
    texture: str | None = None


Marker = Annotated[LedArrayMarker | QrMarker | SquareMarker, Field(discriminator="kind")]


# -- the scene -------------------------------------------------------------------------------
class DockBody(Record):
    T_world_dock: Matrix
    body_size_m: Vec3
    face_color: Vec3


class ObstacleRecord(Record):
    kind: Literal["box", "cylinder", "rock"]
    T_world: Matrix
    size_m: Vec3
    color: Vec3
    object_index: int


class DirectionalLight(Record):
    direction: Vec3 = Field(description="travel direction of the light, world, unit")
    strength: float = Field(description="irradiance W/m^2 normal to the direction")


class SkyRecord(Record):
    upper: float = Field(description="W/m^2/sr")
    lower: float


class WorldLookRecord(Record):
    textures: bool
    texture_seed: int
    tile_size_m: float
    grime: float
    seabed_depth_m: float


class WaterVolume(Record):
    """Reference fidelity: the medium box (its top face is the water surface)."""

    sigma_a: Vec3
    sigma_s: Vec3
    phase: str
    g: float
    ff_ior: float
    ff_backscatter: float
    box_min: Vec3
    box_max: Vec3


class SurfaceSun(Record):
    to_sun: Vec3
    irradiance: float


class CausticsRecord(Record):
    bin_m: float
    dock_bin_m: float
    photons_per_bin: float
    renders: int
    pool_spot: bool


class WaterSurface(Record):
    """Reference fidelity: the refracting surface (``plan.water_surface``)."""

    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset({"caustics"})
    z: float
    centre_xy: list[float]
    half_xy: list[float]
    sky_radiance: float
    wind_mps: float
    wave_seed: int
    sun: SurfaceSun | None
    caustics: CausticsRecord | None = None


class ParticlesRecord(Occlusion):
    """Real-geometry particles (validation mode): the sequence's occlusion and its seed."""

    region_min: Vec3
    region_max: Vec3
    v_flow: Vec3
    seed: int
    fps: float
    object_index: int


class RenderScene(Record):
    """The scene the renderer builds (``plan.scene_description`` plus the per-job water)."""

    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset(
        {"lamps", "water_volume", "led_lights", "water_surface", "particles"}
    )
    pool: Pool | None
    dock: DockBody
    markers: list[Marker]
    obstacles: list[ObstacleRecord]
    object_index: dict[str, int]
    sun: DirectionalLight
    fill: DirectionalLight
    world_color: Vec3
    sky: SkyRecord | None
    world: WorldLookRecord
    lamps: list[Lamp] | None = None
    water_volume: WaterVolume | None = None
    led_lights: bool | None = None
    water_surface: WaterSurface | None = None
    particles: ParticlesRecord | None = None


class RenderSettings(Record):
    """Cycles settings of one job (``plan.render_settings``)."""

    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset({"normal_pass", "sun_pass"})
    samples: int
    threads: int
    max_bounces: int
    diffuse_bounces: int
    volume_bounces: int
    seed: int
    specular_bounces: int
    ambient_radiance: float = Field(description="fast fidelity: W/m^2/sr of the diffuse light field")
    albedo_pass: bool
    write_depth: bool
    write_index: bool
    roi: bool
    background_scale: float
    background_samples: int
    roi_max_fraction: float
    light_tree: bool
    normal_pass: bool | None = None
    sun_pass: bool | None = None


class FramePlan(Record):
    """One planned frame: sample ``index`` of the path at time ``t`` (s), the pose it is rendered
    at, and where samples go (``roi``: one box around the dock; ``rois``: per-marker boxes,
    (x0, y0, x1, y1) px, end-exclusive); ``blur_px`` the dock's image motion over the exposure."""

    OPTIONAL_KEYS: ClassVar[frozenset[str]] = frozenset({"blur_px", "roi", "rois"})
    index: int
    t: float
    t_pose: float
    T_world_cam: Matrix
    blur_px: list[float] | None = None
    roi: list[int] | None = None
    rois: list[list[int]] | None = None

    def plain(self) -> dict:
        """The frame as the plain dict the image-space stages read (given keys only)."""
        return self.model_dump(mode="json")
