//! Flow estimators by name: what configuration files and command lines select.

use crate::dis::{Dis, DisParams};
use crate::estimator::{FlowError, FlowEstimator, LucasKanade};

/// Names accepted by [`flow_estimator_by_name`] in every build; builds with the `onnx` feature
/// also accept `net` (our trained network) and `onnx:MODEL.onnx`.
pub const FLOW_ESTIMATOR_NAMES: [&str; 2] = ["lk", "dis"];

/// Check that `name` names an estimator this build can make, without making it (an ONNX model
/// is not loaded).
///
/// # Errors
/// [`FlowError::Config`] naming the unknown estimator and listing the known ones.
pub fn check_estimator_name(name: &str) -> Result<(), FlowError> {
    let known = FLOW_ESTIMATOR_NAMES.contains(&name)
        || (cfg!(feature = "onnx") && (name == "net" || name.strip_prefix("onnx:").is_some_and(|p| !p.is_empty())));
    if known {
        return Ok(());
    }
    let onnx = if cfg!(feature = "onnx") {
        ", net (our network) or onnx:MODEL.onnx"
    } else {
        "; net and onnx:MODEL.onnx need a build with the `onnx` feature"
    };
    Err(FlowError::Config(format!("unknown estimator '{name}' (available: {}{onnx})", FLOW_ESTIMATOR_NAMES.join(", "))))
}

/// The estimator called `name`: `lk` with the parameters `lk`, `dis` with `dis`, and with the
/// `onnx` feature `net` (the shipped network) or `onnx:MODEL.onnx` (a model and the contract
/// `MODEL.toml` beside it).
///
/// # Errors
/// [`FlowError::Config`] for an unknown name or parameters out of range; [`FlowError::Model`]
/// when an ONNX model cannot be loaded.
///
/// ```
/// use flowfilter_flow::dis::DisParams;
/// use flowfilter_flow::{LucasKanade, flow_estimator_by_name};
/// let dis = flow_estimator_by_name("dis", &LucasKanade::default(), &DisParams::medium())?;
/// assert_eq!(dis.name(), "dis");
/// assert!(flow_estimator_by_name("farneback", &LucasKanade::default(), &DisParams::medium()).is_err());
/// # Ok::<(), flowfilter_flow::FlowError>(())
/// ```
pub fn flow_estimator_by_name(
    name: &str,
    lk: &LucasKanade,
    dis: &DisParams,
) -> Result<Box<dyn FlowEstimator>, FlowError> {
    check_estimator_name(name)?;
    match name {
        "lk" => {
            lk.validate()?;
            Ok(Box::new(lk.clone()))
        }
        "dis" => Ok(Box::new(Dis::new(dis.clone())?)),
        #[cfg(feature = "onnx")]
        "net" => Ok(Box::new(crate::net::ffnet()?)),
        #[cfg(feature = "onnx")]
        other if other.starts_with("onnx:") => {
            Ok(Box::new(crate::onnx::OnnxFlow::load(std::path::Path::new(&other["onnx:".len()..]))?))
        }
        other => Err(FlowError::Config(format!("unknown estimator '{other}'"))),
    }
}

/// The DIS presets by name (`dis-medium`, `dis-fast`, `dis-ultrafast`), besides `dis` (the
/// medium preset).
pub const DIS_PRESET_NAMES: [&str; 3] = ["dis-medium", "dis-fast", "dis-ultrafast"];

/// The estimator called `name` with default parameters, as `flowfilter flow --method` and the
/// Python package's `flow()` name them: the names of [`flow_estimator_by_name`] (Lucas-Kanade
/// with [`LucasKanade::turntable`]'s 9-pixel window, DIS with the medium preset) and the DIS
/// presets of [`DIS_PRESET_NAMES`].
///
/// # Errors
/// As [`flow_estimator_by_name`]; the message also lists the presets.
///
/// ```
/// let fast = flowfilter_flow::flow_estimator_with_presets("dis-fast")?;
/// assert_eq!(fast.name(), "dis");
/// # Ok::<(), flowfilter_flow::FlowError>(())
/// ```
pub fn flow_estimator_with_presets(name: &str) -> Result<Box<dyn FlowEstimator>, FlowError> {
    let (estimator, dis) = match name {
        "dis-medium" => ("dis", DisParams::medium()),
        "dis-fast" => ("dis", DisParams::fast()),
        "dis-ultrafast" => ("dis", DisParams::ultrafast()),
        other => (other, DisParams::medium()),
    };
    flow_estimator_by_name(estimator, &LucasKanade::turntable(), &dis).map_err(|e| match e {
        FlowError::Config(m) => FlowError::Config(format!("{m} (also: {})", DIS_PRESET_NAMES.join(", "))),
        other => other,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_checked_without_building() {
        check_estimator_name("lk").unwrap();
        check_estimator_name("dis").unwrap();
        let e = check_estimator_name("raft").unwrap_err().to_string();
        assert!(e.contains("'raft'") && e.contains("lk, dis"), "{e}");
        assert!(check_estimator_name("onnx:").is_err());
        let lk = flow_estimator_by_name("lk", &LucasKanade::turntable(), &DisParams::medium()).unwrap();
        assert_eq!(lk.name(), "lk");
        let bad = LucasKanade { window: 4, ..LucasKanade::default() };
        assert!(flow_estimator_by_name("lk", &bad, &DisParams::medium()).is_err());
    }
}
