//! The project's own optical-flow network, `ffnet` (feature `onnx`): a SPyNet-class
//! coarse-to-fine network trained by `tools/train-flow/` on synthesised turntable pairs and
//! FlyingChairs-like layers, shipped in this crate's `models/` (see `models/MODEL_CARD.md`) and embedded
//! in the binary, so `--method net` / `estimator = "net"` need no file at run time.

use crate::estimator::FlowError;
use crate::onnx::{OnnxContract, OnnxFlow};

/// The ONNX graph (weights included).
pub const MODEL: &[u8] = include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/models/ffnet.onnx"));

/// Its input/output contract.
pub const CONTRACT: &str = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/models/ffnet.toml"));

/// The shipped network as a flow estimator named `net`.
pub fn ffnet() -> Result<OnnxFlow, FlowError> {
    OnnxFlow::from_bytes("net", MODEL, OnnxContract::from_toml(CONTRACT, "ffnet.toml")?)
}
