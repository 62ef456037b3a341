"""Flow Filter: relative 6-DoF pose of partially seen rigid objects from RGB-D.

NumPy arrays in and out. Registration of two clouds (``register``: ICP, CPD, FilterReg and Flow
Filter, a faster replacement for Open3D's ``registration_icp`` and probreg's
``registration_filterreg``), the whole pipeline on two RGB-D frames (``estimate``), dense
optical flow (``flow``), flow correspondences (``correspondences``), normals
(``estimate_normals``) and readers for PLY clouds, camera files, RGB-D files, BigBIRD objects and
BOP scenes. ``flowfilter.open3d`` has Open3D's ``registration_icp`` API on our ICP; Open3D's
point clouds, images, RGB-D images and pinhole intrinsics are taken as they are.

Every error is a ``flowfilter.Error``: ``InputError`` for arrays and files that cannot be used,
``ConfigError`` for unknown methods and bad parameters. Calls release the GIL and run on the
package's thread pool (``set_num_threads``); results do not depend on the number of threads.
"""

from ._flowfilter import (
    DEFAULT_KNN,
    METHODS,
    Camera,
    ConfigError,
    Correspondences,
    Error,
    Estimate,
    Frame,
    InputError,
    RegistrationResult,
    Tracker,
    __version__,
    bigbird_motion,
    bop_motion,
    bop_objects,
    correspondences,
    default_config,
    default_params,
    estimate,
    estimate_normals,
    evaluate_registration,
    flow,
    get_num_threads,
    global_registration,
    read_bigbird_frame,
    read_bop_frame,
    read_camera,
    read_frame,
    read_ply,
    register,
    set_num_threads,
    write_ply,
)

__all__ = [
    "DEFAULT_KNN",
    "METHODS",
    "Camera",
    "ConfigError",
    "Correspondences",
    "Error",
    "Estimate",
    "Frame",
    "InputError",
    "RegistrationResult",
    "Tracker",
    "__version__",
    "bigbird_motion",
    "bop_motion",
    "bop_objects",
    "correspondences",
    "default_config",
    "default_params",
    "estimate",
    "estimate_normals",
    "evaluate_registration",
    "flow",
    "get_num_threads",
    "global_registration",
    "read_bigbird_frame",
    "read_bop_frame",
    "read_camera",
    "read_frame",
    "read_ply",
    "register",
    "set_num_threads",
    "write_ply",
]
