"""Type stubs of flowfilter's compiled module (crates/flowfilter-py/src)."""

import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str
METHODS: List[str]
"""Registration methods `register` and `estimate` accept."""
DEFAULT_KNN: int
"""The depth stage's k for k-NN normals (`[depth.cloud] knn`), the default of `estimate_normals`."""

PathLike = Union[str, "os.PathLike[str]"]
ArrayLike = npt.NDArray[Any]
CameraLike = Union["Camera", PathLike, Dict[str, Any]]
ConfigLike = Union[PathLike, Dict[str, Any], None]

class Error(Exception):
    """Base of every error flowfilter raises; the message names the array, file or key at fault."""

class InputError(Error):
    """An array, file or frame that cannot be used: wrong shape or dtype, NaN, empty, sizes that disagree."""

class ConfigError(Error):
    """A method name, parameter or configuration value that is unknown or out of range."""

class RegistrationResult:
    """The result of `register`: Open3D's `RegistrationResult` fields and the backend's report."""

    @property
    def transformation(self) -> npt.NDArray[np.float64]:
        """The 4x4 transform `T` with `target ~ T @ source`."""
    @property
    def fitness(self) -> float:
        """Fraction of source points with a target neighbour within the inlier distance."""
    @property
    def inlier_rmse(self) -> float:
        """RMSE of those inlier pairs, metres."""
    @property
    def iterations(self) -> int:
        """Iterations run."""
    @property
    def converged(self) -> bool:
        """Whether the backend's convergence criterion was met."""
    @property
    def sigma2(self) -> Optional[float]:
        """Final sigma^2 (m^2) of the GMM backends (CPD, FilterReg, Flow Filter); None for ICP."""
    @property
    def scale(self) -> Optional[float]:
        """CPD's scale when scale estimation is on, else None."""
    @property
    def method(self) -> str:
        """The backend's name."""
    @property
    def seconds(self) -> float:
        """Seconds spent inside the backend (the rest of the call is the binding's)."""
    @property
    def warnings(self) -> List[Dict[str, str]]:
        """Conditions to know about, as dicts {"code", "message"}."""
    @property
    def uncertainty(self) -> Optional[Dict[str, float]]:
        """Error bounds {"rotation_deg", "translation_m"} when the backend gives them."""
    def to_dict(self) -> Dict[str, Any]:
        """The result as `flowfilter register --json` prints it (schema "flowfilter register v1")."""

class Camera:
    """A camera: intrinsics, optional image size and distortion, the depth unit, and optionally a
    separate depth camera (in a camera file)."""

    def __init__(
        self,
        K: Union[ArrayLike, Sequence[Sequence[float]], Sequence[float]],
        width: Optional[int] = None,
        height: Optional[int] = None,
        depth_unit: Optional[float] = None,
        distortion: Optional[Sequence[float]] = None,
    ) -> None:
        """A camera from its 3x3 intrinsic matrix `K` (pixels), optional `width` and `height`
        (else the images' size), `depth_unit` (metres per raw depth unit, e.g. 0.001 for
        millimetres) and `distortion` (k1, k2, p1, p2, k3: OpenCV's order)."""
    @staticmethod
    def from_file(path: PathLike) -> "Camera":
        """A camera file: this project's JSON, a BOP scene_camera.json entry or camera.json, or
        Open3D's PinholeCameraIntrinsic JSON."""
    @staticmethod
    def from_dict(d: Dict[str, Any]) -> "Camera":
        """A camera from a dict in any of the camera-file layouts."""
    @property
    def K(self) -> npt.NDArray[np.float64]:
        """The 3x3 intrinsic matrix."""
    @property
    def width(self) -> Optional[int]:
        """Image width, when the camera gives it."""
    @property
    def height(self) -> Optional[int]:
        """Image height, when the camera gives it."""
    @property
    def depth_unit(self) -> Optional[float]:
        """Metres per raw depth unit, when the camera gives it."""
    @property
    def is_registered(self) -> bool:
        """Whether depth is registered to colour (no separate depth camera)."""

class Frame:
    """One RGB-D view: colour (H, W, 3) uint8, depth (H, W) uint16 raw units (with
    `depth_scale`) or float32 metres, and an optional object mask (H, W) bool."""

    def __init__(
        self,
        color: npt.NDArray[np.uint8],
        depth: Union[npt.NDArray[np.uint16], npt.NDArray[np.float32], npt.NDArray[np.float64]],
        mask: Optional[npt.NDArray[np.bool_]] = None,
        depth_scale: Optional[float] = None,
        name: str = "frame",
    ) -> None:
        """A frame from arrays (or `open3d.geometry.Image`s). `depth_scale`: raw units per metre for uint16 depth (Open3D's
        convention: 1000.0 for millimetres); without it the camera's depth unit applies. Float
        depth is metres (NaN, inf and 0: no reading). Without a mask the object is the whole
        image."""
    @property
    def name(self) -> str:
        """The frame's name."""
    @property
    def color(self) -> npt.NDArray[np.uint8]:
        """Colour image, (H, W, 3)."""
    @property
    def depth(self) -> Union[npt.NDArray[np.uint16], npt.NDArray[np.float32]]:
        """Depth as given: (H, W) uint16 raw units or float32 metres."""
    @property
    def mask(self) -> Optional[npt.NDArray[np.bool_]]:
        """Object mask (H, W), or None when not given."""
    @property
    def depth_unit(self) -> Optional[float]:
        """Metres per raw depth unit, when known without a camera."""
    @property
    def K(self) -> Optional[npt.NDArray[np.float64]]:
        """The colour camera's intrinsic matrix of a frame read from a dataset, else None."""

class Estimate:
    """The pipeline's estimate: the fields of `flowfilter estimate --json` (schema
    "flowfilter estimate v3")."""

    @property
    def transform(self) -> npt.NDArray[np.float64]:
        """The 4x4 transform `T` with `target ~ T @ model` (colour camera frame)."""
    @property
    def transformation(self) -> npt.NDArray[np.float64]:
        """The same as `transform` (Open3D's name)."""
    @property
    def method(self) -> str:
        """Registration method."""
    @property
    def flow_estimator(self) -> Optional[str]:
        """Flow estimator, for methods that use flow."""
    @property
    def model(self) -> str:
        """Model frame's name."""
    @property
    def target(self) -> str:
        """Target frame's name."""
    @property
    def rotation_angle_deg(self) -> float:
        """Rotation angle of `T`, degrees."""
    @property
    def rotation_axis(self) -> List[float]:
        """Unit rotation axis of `T` ([0, 0, 0] without rotation)."""
    @property
    def translation_m(self) -> List[float]:
        """Translation of `T`, metres."""
    @property
    def registration(self) -> Dict[str, Any]:
        """iterations, converged, fitness, inlier_rmse_m, sigma2, model_points, target_points and,
        for Flow Filter, uncertainty."""
    @property
    def correspondences(self) -> Optional[Dict[str, Any]]:
        """tracked, consistent, inliers, guided; None without flow."""
    @property
    def stage_ms(self) -> Dict[str, float]:
        """Milliseconds per stage."""
    @property
    def warnings(self) -> List[Dict[str, str]]:
        """Conditions to know about, as dicts {"code", "message"}."""
    @property
    def judge(self) -> Optional[Dict[str, Any]]:
        """What the photometric judge saw (answer_score, candidates, best_score, best_turn_deg,
        best_axis, retracked_score, replaced, answer_transform, retracked_transform,
        aligned_answer_score, aligned_candidate); None for methods without flow and where the
        texture is flat."""
    @property
    def align(self) -> Optional[Dict[str, Any]]:
        """What the direct alignment did (pixels, iterations, cost_before, cost_after, turn_deg,
        shift_m, row_shear_px_per_row, accepted); None for methods without flow and where the images cannot be aligned."""
    @property
    def geometry_first(self) -> Optional[Dict[str, Any]]:
        """A scene's geometry-first try (confirmed, registration_converged, score,
        visible_fraction): whether its geometric registration was kept without flow; None where
        no try ran (not a scene, not a Flow Filter method)."""
    @property
    def ground_truth(self) -> Optional[Dict[str, Any]]:
        """The true transform and the errors against it, when `gt` was given."""
    def to_dict(self) -> Dict[str, Any]:
        """The estimate as `flowfilter estimate --json` prints it."""
    @property
    def state(self) -> Optional[str]:
        """For `Tracker.update`'s estimates: the track's state (`tracking`, `uncertain`, `lost`,
        `recovered`); None for a pairwise estimate."""
    @property
    def reason(self) -> Optional[str]:
        """For `Tracker.update`'s estimates: why the state is not `tracking` (or what the estimate warned of)."""
    @property
    def reference(self) -> Optional[int]:
        """For `Tracker.update`'s estimates: the stream index of the frame measured against."""
    @property
    def keyframe(self) -> Optional[bool]:
        """For `Tracker.update`'s estimates: whether this frame became a keyframe."""
    @property
    def aligned_only(self) -> Optional[bool]:
        """For `Tracker.update`'s estimates: whether the pose came from direct alignment alone
        from the motion's prediction, confirmed on the images (no flow, registration or judge)."""
    @property
    def prepared_region(self) -> Optional[Tuple[int, int, int, int]]:
        """For `Tracker.update`'s estimates: the part of the image the frame was prepared on,
        `(x, y, width, height)` in pixels (the object's predicted region); None for the whole
        image (and for pair estimates)."""
    @property
    def frame_index(self) -> Optional[int]:
        """For `Tracker.update`'s estimates: the frame's index in the stream (0: the first)."""
    def log_to_rerun(
        self, model: Optional[Frame] = None, target: Optional[Frame] = None, recording: Any = None, step: int = 0
    ) -> None:
        """Log the estimate to Rerun (needs rerun-sdk) at the entity paths of `flowfilter estimate
        --rerun` (docs/rerun.md), at step `step` of the `pair` timeline; with `model`/`target`, their
        colour, depth and masks too. `recording`: a `rerun.RecordingStream` (None: the current one)."""

class Tracker:
    """Tracks an object through a stream of RGB-D frames from its mask in the first frame (without
    one, the whole scene); `update(frame)` returns the motion from the first frame as an
    `Estimate` with the track's `state`, `reason`, `reference`, `keyframe`, `frame_index`."""

    def __init__(
        self,
        camera: Optional[CameraLike],
        frame: Union[Frame, Any],
        mask: Optional[ArrayLike] = None,
        config: ConfigLike = None,
        bbox: Optional[Tuple[int, int, int, int]] = None,
        settings: Optional[Dict[str, Any]] = None,
    ) -> None:
        """Start on `frame`; `mask` ((H, W) bool, or the frame's own) is the object's, or `bbox`
        (x, y, w, h) a box around it; `settings` the tracker's own (`TrackerConfig`'s keys, e.g.
        `{"aligned_path": True}`)."""
    def update(self, frame: Union[Frame, Any]) -> Estimate:
        """The next frame: the object's motion from the first frame, with the track's state. A frame
        that cannot be used is `lost` with the reason, not an exception."""
    def keyframes(self) -> List[int]:
        """Stream indices of the keyframes held now."""
    def object_mask(self) -> Optional[npt.NDArray[np.bool_]]:
        """The object's mask in the last frame as the tracker carried it there, (H, W) bool (with the
        `reveal` setting, grown onto the faces turning into view); None for the whole scene or
        after a lost frame."""

class Correspondences:
    """Flow correspondences: model points and where the flow puts them in the target frame."""

    @property
    def source(self) -> npt.NDArray[np.float64]:
        """Model-frame points, (K, 3), metres."""
    @property
    def target(self) -> npt.NDArray[np.float64]:
        """Target-frame points, (K, 3)."""
    @property
    def weights(self) -> npt.NDArray[np.float64]:
        """Weights in [0, 1], (K,) (0: rejected by the depth-change fit)."""
    @property
    def tracked(self) -> int:
        """Model pixels tracked before any check."""
    def __len__(self) -> int: ...

def register(
    source: ArrayLike,
    target: ArrayLike,
    method: str = "filterreg-pt2pt",
    init: Optional[ArrayLike] = None,
    target_normals: Optional[ArrayLike] = None,
    *,
    source_normals: Optional[ArrayLike] = None,
    correspondences: Optional[Tuple[ArrayLike, ...]] = None,
    **params: Any,
) -> RegistrationResult:
    """Align `source` to `target`: the rigid `T` with `target ~ T @ source`.

    `source`, `target`: (N, 3) float32 or float64 arrays (any memory layout), or
    `open3d.geometry.PointCloud`s (their normals used when they have them). `method`: one of
    `METHODS`. `init`: a 4x4 initial transform. `target_normals` (and `source_normals`): (N, 3)
    normals for the point-to-plane methods (see `estimate_normals`). `correspondences`:
    `(source_points, target_points[, weights])` for the Flow Filter methods. `**params`: the
    backend's parameters with the names and defaults of its TOML table (`default_params(method)`).

    Raises InputError for arrays that cannot be used, ConfigError for an unknown method or
    parameter or a value out of range.
    """

def evaluate_registration(
    source: ArrayLike, target: ArrayLike, max_correspondence_distance: float, transformation: Optional[ArrayLike] = None
) -> Tuple[float, float, npt.NDArray[np.int64]]:
    """How well `transformation` (4x4, default identity) aligns `source` to `target` (Open3D's
    `evaluate_registration`): `(fitness, inlier_rmse, correspondence_set)`, the pairs a (K, 2)
    int64 array of (source index, target index) within `max_correspondence_distance`. Clouds are
    (N, 3) arrays or `open3d.geometry.PointCloud`s.

    Raises InputError for arrays that cannot be used or a distance that is not positive."""

def global_registration(
    source: ArrayLike, target: ArrayLike, voxel_size: float = 0.005
) -> Optional[Tuple[npt.NDArray[np.float64], int, int]]:
    """A start for `register` from nowhere (Open3D's global registration, then point-to-plane
    ICP; `flowfilter register --global`): both clouds thinned to at most 2500 points from
    `voxel_size` (metres) up, FPFH descriptors matched both ways, a RANSAC over three matches.
    `(transformation, inliers, matches)`: the 4x4 transform with `target ~ T @ source` and how
    many of the mutual descriptor matches agree with it; None when no motion gathers 12 of them.

    Raises InputError for arrays that cannot be used or a voxel size that is not positive."""

def estimate(
    model: Union[Frame, Any],
    target: Union[Frame, Any],
    camera: Optional[CameraLike] = None,
    method: Optional[str] = "flowfilter",
    config: ConfigLike = None,
    *,
    gt: Optional[ArrayLike] = None,
) -> Estimate:
    """The relative pose of the object between two RGB-D frames of one camera.

    `model`, `target`: `Frame`s or `open3d.geometry.RGBDImage`s. `camera`: required for frames
    made from arrays (a `Camera`, an `open3d.camera.PinholeCameraIntrinsic`, a camera-file path or
    a dict). `method` replaces the configuration's (None
    keeps it). `config`: a TOML file path or a dict of its tables (`default_config()`). `gt`: the
    true 4x4 motion, for `ground_truth`.
    """

def correspondences(
    model: Frame,
    target: Frame,
    camera: Optional[CameraLike] = None,
    config: ConfigLike = None,
    init: Optional[ArrayLike] = None,
) -> Correspondences:
    """The pipeline's flow correspondences between two frames; `init` guides tracking."""

def flow(
    image1: ArrayLike,
    image2: ArrayLike,
    method: str = "dis",
    mask: Optional[npt.NDArray[np.bool_]] = None,
) -> npt.NDArray[np.float32]:
    """Dense optical flow from `image1` to `image2`: (H, W, 2) displacements in pixels, NaN where
    there is none. Images: (H, W, 3) uint8, (H, W) uint8, or (H, W) float32 in [0, 1]. `method`:
    dis, dis-medium, dis-fast, dis-ultrafast, lk (and net, onnx:MODEL.onnx with the onnx feature)."""

def estimate_normals(
    points: ArrayLike, k: int = 20, viewpoint: Tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> npt.NDArray[np.float64]:
    """Unit normals by PCA over each point's `k` nearest neighbours, turned to face `viewpoint`."""

def read_ply(path: PathLike) -> Tuple[npt.NDArray[np.float64], Optional[npt.NDArray[np.float64]]]:
    """A PLY point cloud: (points, normals), normals None when the file has none."""

def write_ply(path: PathLike, points: ArrayLike, normals: Optional[ArrayLike] = None, binary: bool = True) -> None:
    """Write points (and normals) as a PLY file."""

def read_camera(path: PathLike) -> Camera:
    """A camera file in any of the supported layouts."""

def read_frame(
    color: PathLike,
    depth: PathLike,
    camera: CameraLike,
    mask: Optional[PathLike] = None,
    label: Optional[int] = None,
    name: Optional[str] = None,
) -> Frame:
    """One RGB-D frame from files: colour PNG/JPEG, 16-bit depth PNG, optional binary or label mask."""

def read_bigbird_frame(object_dir: PathLike, camera: str, angle: int) -> Frame:
    """One frame of a BigBIRD-layout object: camera NP1..NP5 at a turntable angle (degrees)."""

def bigbird_motion(object_dir: PathLike, camera: str, from_angle: int, to_angle: int) -> npt.NDArray[np.float64]:
    """The true 4x4 motion between two turntable angles in a camera's colour frame."""

def read_bop_frame(scene_dir: PathLike, im_id: int, obj_id: int) -> Frame:
    """One object in one image of a BOP scene folder, with its visible mask."""

def bop_motion(scene_dir: PathLike, im_a: int, im_b: int, obj_id: int) -> npt.NDArray[np.float64]:
    """The true 4x4 motion of an object from image `im_a` to image `im_b` of a BOP scene."""

def bop_objects(scene_dir: PathLike) -> List[Tuple[int, List[int]]]:
    """The image ids of a BOP scene and the object ids annotated in each."""

def set_num_threads(n: int) -> None:
    """Set the number of worker threads of later calls (0: one per core)."""

def get_num_threads() -> int:
    """The number of worker threads calls run on."""

def default_params(method: str) -> Dict[str, Any]:
    """The defaults of a registration method's parameters (its TOML table)."""

def default_config() -> Dict[str, Any]:
    """The default pipeline configuration as a dict of its tables."""
