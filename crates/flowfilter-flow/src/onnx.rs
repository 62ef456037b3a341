//! Any ONNX optical-flow network as a [`FlowEstimator`] (cargo feature `onnx`, through
//! tract-onnx).
//!
//! A network is described by a TOML **contract** beside it (`model.onnx` -> `model.toml`), so
//! that networks exported in different conventions can be used unchanged:
//!
//! ```toml
//! [input]
//! names = ["from", "to"]   # two inputs (one image each), or one name: both images concatenated on channels
//! channels = 1             # per image: 1 (grey) or 3 (grey replicated to RGB)
//! scale = 1.0              # pixel values in [0, 1] are multiplied by this...
//! mean = [0.0]             # ...then each channel has its mean subtracted...
//! std = [1.0]              # ...and is divided by its std
//! size_multiple = 8        # dynamic sizes: images padded (border replicated) up to a multiple
//! # fixed_size = [64, 48]  # or: the network takes exactly width x height (images resized, flow rescaled)
//! [output]
//! name = "flow"            # the output holding [1, 2, H / downsample, W / downsample]
//! scale = 1.0              # network units -> pixels at the output's resolution
//! downsample = 1
//! ```
//!
//! Every mismatch between the contract and the network (an input or output name, the channel
//! count, the output's shape) is a [`FlowError::Model`] naming the file and the problem.

use crate::FlowField;
use crate::estimator::{FlowError, FlowEstimator, check_pair};
use crate::lk::{Gray, bilinear};
use flowfilter_geometry::{Grid, Mask};
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use tract_onnx::prelude::*;

fn one() -> f32 {
    1.0
}

fn one_usize() -> usize {
    1
}

/// How the network's inputs are built.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputContract {
    /// Input names: two (one image each) or one (both images concatenated on channels).
    pub names: Vec<String>,
    /// Channels per image: 1 (grey) or 3 (grey replicated).
    pub channels: usize,
    /// Multiplier of the [0, 1] pixel values.
    #[serde(default = "one")]
    pub scale: f32,
    /// Per-channel mean subtracted after scaling (empty: 0).
    #[serde(default)]
    pub mean: Vec<f32>,
    /// Per-channel standard deviation divided by (empty: 1).
    #[serde(default)]
    pub std: Vec<f32>,
    /// Dynamic sizes are padded up to a multiple of this.
    #[serde(default = "one_usize")]
    pub size_multiple: usize,
    /// A fixed `[width, height]` the network requires.
    #[serde(default)]
    pub fixed_size: Option<[usize; 2]>,
}

/// How the network's output is read.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputContract {
    /// The output's name.
    pub name: String,
    /// Network units to pixels (at the output's resolution).
    #[serde(default = "one")]
    pub scale: f32,
    /// Input size / output size.
    #[serde(default = "one_usize")]
    pub downsample: usize,
}

/// A network's input/output contract (the TOML sidecar).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OnnxContract {
    /// Inputs.
    pub input: InputContract,
    /// Output.
    pub output: OutputContract,
}

impl OnnxContract {
    /// Read a contract file.
    pub fn from_file(path: &Path) -> Result<Self, FlowError> {
        let err = |message: String| FlowError::Model { path: path.display().to_string(), message };
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read the contract: {e}")))?;
        Self::from_toml(&text, &path.display().to_string())
    }

    /// Parse a contract from TOML text; `label` names it in errors.
    pub fn from_toml(text: &str, label: &str) -> Result<Self, FlowError> {
        let err = |message: String| FlowError::Model { path: label.to_string(), message };
        let c: Self = toml::from_str(text).map_err(|e| err(format!("contract: {}", e.message().trim())))?;
        c.validate().map_err(err)?;
        Ok(c)
    }

    /// Check the contract's own consistency.
    pub fn validate(&self) -> Result<(), String> {
        let i = &self.input;
        if !(1..=2).contains(&i.names.len()) {
            return Err(format!("input.names must list 1 or 2 inputs, found {}", i.names.len()));
        }
        if i.channels != 1 && i.channels != 3 {
            return Err(format!("input.channels must be 1 or 3, found {}", i.channels));
        }
        for (what, v) in [("mean", &i.mean), ("std", &i.std)] {
            if !v.is_empty() && v.len() != i.channels {
                return Err(format!("input.{what} has {} values for {} channels", v.len(), i.channels));
            }
        }
        if i.std.contains(&0.0) || i.size_multiple == 0 || self.output.downsample == 0 {
            return Err("input.std must be non-zero; size_multiple and output.downsample >= 1".into());
        }
        if let Some([w, h]) = i.fixed_size
            && (w == 0 || h == 0)
        {
            return Err("input.fixed_size must be positive".into());
        }
        Ok(())
    }
}

type Plan = Arc<TypedRunnableModel>;

/// An ONNX flow network with its contract.
pub struct OnnxFlow {
    path: PathBuf,
    contract: OnnxContract,
    /// Input indices of the network in contract order.
    input_order: Vec<usize>,
    /// Index of the contract's output among the network's outputs.
    output_index: usize,
    model: InferenceModel,
    plans: Mutex<HashMap<(usize, usize), Plan>>,
    name: String,
}

impl std::fmt::Debug for OnnxFlow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxFlow").field("path", &self.path).field("contract", &self.contract).finish()
    }
}

impl OnnxFlow {
    /// Load `model` with the contract beside it (`model` with the extension `.toml`).
    pub fn load(model: &Path) -> Result<Self, FlowError> {
        let contract = OnnxContract::from_file(&model.with_extension("toml"))?;
        Self::with_contract(model, contract)
    }

    /// Load `model` with a given contract.
    pub fn with_contract(model: &Path, contract: OnnxContract) -> Result<Self, FlowError> {
        let err = |message: String| FlowError::Model { path: model.display().to_string(), message };
        contract.validate().map_err(err)?;
        let proto = tract_onnx::onnx().model_for_path(model).map_err(|e| err(format!("cannot load: {e:#}")))?;
        let name = format!("onnx:{}", model.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned()));
        Self::from_proto(model, proto, contract, name)
    }

    /// A network held in memory (`onnx` bytes) with its contract; `label` names it in errors
    /// and is the estimator's name.
    pub fn from_bytes(label: &str, onnx: &[u8], contract: OnnxContract) -> Result<Self, FlowError> {
        let err = |message: String| FlowError::Model { path: label.to_string(), message };
        contract.validate().map_err(err)?;
        let proto =
            tract_onnx::onnx().model_for_read(&mut &onnx[..]).map_err(|e| err(format!("cannot load: {e:#}")))?;
        Self::from_proto(Path::new(label), proto, contract, label.to_string())
    }

    fn from_proto(
        model: &Path,
        proto: InferenceModel,
        contract: OnnxContract,
        name: String,
    ) -> Result<Self, FlowError> {
        let err = |message: String| FlowError::Model { path: model.display().to_string(), message };
        let inputs: Vec<String> = proto
            .input_outlets()
            .map_err(|e| err(e.to_string()))?
            .iter()
            .map(|o| proto.node(o.node).name.clone())
            .collect();
        let input_order = contract
            .input
            .names
            .iter()
            .map(|n| {
                inputs.iter().position(|m| m == n).ok_or_else(|| {
                    err(format!(
                        "the contract's input '{n}' is not an input of the network (inputs: {})",
                        inputs.join(", ")
                    ))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        if inputs.len() != contract.input.names.len() {
            return Err(err(format!(
                "the network has {} inputs ({}), the contract names {}",
                inputs.len(),
                inputs.join(", "),
                contract.input.names.len()
            )));
        }
        let outputs: Vec<String> = proto
            .output_outlets()
            .map_err(|e| err(e.to_string()))?
            .iter()
            .map(|o| proto.outlet_label(*o).map_or_else(|| proto.node(o.node).name.clone(), str::to_string))
            .collect();
        let output_index = outputs.iter().position(|m| *m == contract.output.name).ok_or_else(|| {
            err(format!(
                "the contract's output '{}' is not an output of the network (outputs: {})",
                contract.output.name,
                outputs.join(", ")
            ))
        })?;
        Ok(Self {
            path: model.to_path_buf(),
            contract,
            input_order,
            output_index,
            model: proto,
            plans: Mutex::new(HashMap::new()),
            name,
        })
    }

    /// The contract.
    pub fn contract(&self) -> &OnnxContract {
        &self.contract
    }

    fn err(&self, message: String) -> FlowError {
        FlowError::Model { path: self.path.display().to_string(), message }
    }

    /// The optimised plan for a network input of `width x height` (built once per size).
    fn plan(&self, width: usize, height: usize) -> Result<Plan, FlowError> {
        if let Some(p) = self.plans.lock().expect("plan cache").get(&(width, height)) {
            return Ok(p.clone());
        }
        let c = &self.contract.input;
        let per_input = if c.names.len() == 2 { c.channels } else { 2 * c.channels };
        let mut model = self.model.clone();
        for &index in &self.input_order {
            model = model
                .with_input_fact(index, f32::fact([1, per_input, height, width]).into())
                .map_err(|e| self.err(format!("input {index}: {e:#}")))?;
        }
        let plan: Plan = model.into_optimized().and_then(|m| m.into_runnable()).map_err(|e| {
            self.err(format!(
                "the network does not accept inputs of [1, {per_input}, {height}, {width}] as the contract \
                     describes them: {e:#}"
            ))
        })?;
        self.plans.lock().expect("plan cache").insert((width, height), plan.clone());
        Ok(plan)
    }

    /// The network input for one image (`[channels, H, W]` values).
    fn normalise(&self, img: &Gray) -> Vec<f32> {
        let c = &self.contract.input;
        let (w, h) = img.dims();
        let mut out = Vec::with_capacity(c.channels * w * h);
        for ch in 0..c.channels {
            let mean = c.mean.get(ch).copied().unwrap_or(0.0);
            let std = c.std.get(ch).copied().unwrap_or(1.0);
            out.extend(img.as_slice().iter().map(|v| (v * c.scale - mean) / std));
        }
        out
    }
    /// Run the network on a pair: the images brought to the network's input size, the output
    /// checked against the contract. Returns the input size `(nw, nh)`, the output size
    /// `(ow, oh)` and the raw output values (`[2, oh, ow]`, network units).
    pub fn network_output(&self, from: &Gray, to: &Gray) -> Result<NetworkOutput, FlowError> {
        check_pair(from, to, None)?;
        let c = &self.contract.input;
        let (w, h) = from.dims();
        // Network input size and the images at it.
        let (nw, nh, a, b) = match c.fixed_size {
            Some([fw, fh]) => (fw, fh, resample(from, fw, fh), resample(to, fw, fh)),
            None => {
                let m = c.size_multiple;
                let (pw, ph) = (w.div_ceil(m) * m, h.div_ceil(m) * m);
                (pw, ph, pad(from, pw, ph), pad(to, pw, ph))
            }
        };
        let plan = self.plan(nw, nh)?;
        let (xa, xb) = (self.normalise(&a), self.normalise(&b));
        let inputs: Vec<Tensor> = if c.names.len() == 2 {
            [xa, xb]
                .into_iter()
                .map(|v| Tensor::from_shape(&[1, c.channels, nh, nw], &v))
                .collect::<TractResult<_>>()
                .map_err(|e| self.err(e.to_string()))?
        } else {
            let both: Vec<f32> = xa.into_iter().chain(xb).collect();
            vec![Tensor::from_shape(&[1, 2 * c.channels, nh, nw], &both).map_err(|e| self.err(e.to_string()))?]
        };
        // The plan's inputs follow the network's order.
        let mut ordered: Vec<Option<Tensor>> = vec![None; inputs.len()];
        for (t, &index) in inputs.into_iter().zip(&self.input_order) {
            ordered[index] = Some(t);
        }
        let values: TVec<TValue> = ordered.into_iter().map(|t| t.expect("every input set").into()).collect();
        let outputs = plan.run(values).map_err(|e| self.err(format!("inference failed: {e:#}")))?;
        let out =
            outputs.get(self.output_index).ok_or_else(|| self.err(format!("output {} missing", self.output_index)))?;
        let d = self.contract.output.downsample;
        let (ow, oh) = (nw / d, nh / d);
        let shape = out.shape().to_vec();
        if shape != [1, 2, oh, ow] {
            return Err(self.err(format!(
                "output '{}' has shape {shape:?}, the contract implies [1, 2, {oh}, {ow}]",
                self.contract.output.name
            )));
        }
        let values: Vec<f32> =
            out.to_plain_array_view::<f32>().map_err(|e| self.err(e.to_string()))?.iter().copied().collect();
        Ok(NetworkOutput { input_size: (nw, nh), output_size: (ow, oh), values })
    }
}

/// The raw output of a network run.
#[derive(Debug, Clone, PartialEq)]
pub struct NetworkOutput {
    /// Network input `(width, height)`.
    pub input_size: (usize, usize),
    /// Output `(width, height)`.
    pub output_size: (usize, usize),
    /// `[2, height, width]` values in network units.
    pub values: Vec<f32>,
}

/// Bilinear resampling of an image to `w x h` (pixel centres aligned).
fn resample(img: &Gray, w: usize, h: usize) -> Gray {
    let (sw, sh) = img.dims();
    let (fx, fy) = (sw as f32 / w as f32, sh as f32 / h as f32);
    Gray::from_fn(w, h, |x, y| bilinear(img, (x as f32 + 0.5) * fx - 0.5, (y as f32 + 0.5) * fy - 0.5))
}

/// The image padded to `w x h` by replicating its last row and column.
fn pad(img: &Gray, w: usize, h: usize) -> Gray {
    let (sw, sh) = img.dims();
    Gray::from_fn(w, h, |x, y| *img.at(x.min(sw - 1), y.min(sh - 1)))
}

impl FlowEstimator for OnnxFlow {
    fn name(&self) -> &str {
        &self.name
    }

    fn dense(&self, from: &Gray, to: &Gray, mask: Option<&Mask>) -> Result<FlowField, FlowError> {
        check_pair(from, to, mask)?;
        let (w, h) = from.dims();
        let NetworkOutput { input_size: (nw, nh), output_size: (ow, oh), values } = self.network_output(from, to)?;
        let d = self.contract.output.downsample;
        let k = self.contract.output.scale * d as f32;
        let (u, v) = (
            Gray::from_fn(ow, oh, |x, y| values[y * ow + x] * k),
            Gray::from_fn(ow, oh, |x, y| values[oh * ow + y * ow + x] * k),
        );
        // Back to the network input's resolution, then to the image's.
        let (u, v) = if d > 1 { (resample(&u, nw, nh), resample(&v, nw, nh)) } else { (u, v) };
        let (u, v) = match self.contract.input.fixed_size {
            Some(_) => {
                let (sx, sy) = (w as f32 / nw as f32, h as f32 / nh as f32);
                (resample(&u, w, h).map(|x| x * sx), resample(&v, w, h).map(|x| x * sy))
            }
            None => (Gray::from_fn(w, h, |x, y| *u.at(x, y)), Gray::from_fn(w, h, |x, y| *v.at(x, y))),
        };
        let flow = Grid::from_vec(w, h, u.as_slice().iter().zip(v.as_slice()).map(|(a, b)| [*a, *b]).collect())
            .expect("sizes");
        let valid = mask.cloned().unwrap_or_else(|| Mask::filled(w, h, true));
        Ok(FlowField { flow, valid })
    }
}
