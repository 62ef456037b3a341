//! Backends by name, configured from one serde struct (one table per backend in TOML).

use crate::cpd::{Cpd, CpdConfig};
use crate::error::RegistrationError;
use crate::filterreg::{FilterReg, FilterRegConfig, FilterRegVariant};
use crate::flowfilter::{FlowFilter, FlowFilterConfig, FlowFilterMode};
use crate::icp::{Icp, IcpConfig, IcpVariant};
use crate::problem::Registrar;
use flowfilter_geometry::ParamError;
use serde::{Deserialize, Serialize};

/// Names accepted by [`registrar_by_name`] (besides the aliases `icp` for `icp-pt2pt` and
/// `filterreg` for `filterreg-pt2pt`). Whether a backend reads correspondences is its own
/// [`Registrar::uses_correspondences`].
pub const METHOD_NAMES: [&str; 8] = [
    "icp-pt2pt",
    "icp-pt2pl",
    "cpd",
    "filterreg-pt2pt",
    "filterreg-pt2pl",
    "flowfilter",
    "flowfilter-init-only",
    "flowfilter-flow-only",
];

/// Parameters of every backend (the variant fields are set from the method name).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegistrationConfig {
    /// ICP.
    pub icp: IcpConfig,
    /// CPD.
    pub cpd: CpdConfig,
    /// FilterReg.
    pub filterreg: FilterRegConfig,
    /// Flow Filter.
    pub flowfilter: FlowFilterConfig,
}

impl RegistrationConfig {
    /// Check every backend's table (keys relative to `[registration]`: `cpd.w`).
    ///
    /// # Errors
    /// The first key at fault.
    pub fn validate(&self) -> Result<(), ParamError> {
        self.icp.validate().map_err(|e| e.within("icp"))?;
        self.cpd.validate().map_err(|e| e.within("cpd"))?;
        self.filterreg.validate().map_err(|e| e.within("filterreg"))?;
        self.flowfilter.validate().map_err(|e| e.within("flowfilter"))
    }
}

/// The backend called `name`, configured by `config`.
///
/// # Errors
/// [`RegistrationError::Config`] for an unknown name (the message lists [`METHOD_NAMES`]) or
/// parameters out of range.
///
/// ```
/// use flowfilter_registration::{RegistrationConfig, registrar_by_name};
/// let config = RegistrationConfig::default();
/// let filterreg = registrar_by_name("filterreg-pt2pl", &config)?;
/// assert_eq!(filterreg.name(), "filterreg-pt2pl");
/// assert!(!filterreg.uses_correspondences());
/// assert!(registrar_by_name("flowfilter", &config)?.uses_correspondences());
/// assert!(registrar_by_name("ndt", &config).is_err());
/// # Ok::<(), flowfilter_registration::RegistrationError>(())
/// ```
pub fn registrar_by_name(name: &str, config: &RegistrationConfig) -> Result<Box<dyn Registrar>, RegistrationError> {
    Ok(match name {
        "icp-pt2pt" | "icp" => {
            Box::new(Icp::new(IcpConfig { variant: IcpVariant::PointToPoint, ..config.icp.clone() })?)
        }
        "icp-pt2pl" => Box::new(Icp::new(IcpConfig { variant: IcpVariant::PointToPlane, ..config.icp.clone() })?),
        "cpd" => Box::new(Cpd::new(config.cpd.clone())?),
        "filterreg-pt2pt" | "filterreg" => Box::new(FilterReg::new(FilterRegConfig {
            variant: FilterRegVariant::PointToPoint,
            ..config.filterreg.clone()
        })?),
        "filterreg-pt2pl" => Box::new(FilterReg::new(FilterRegConfig {
            variant: FilterRegVariant::PointToPlane,
            ..config.filterreg.clone()
        })?),
        "flowfilter" | "flowfilter-init-only" | "flowfilter-flow-only" => {
            let mode = match name {
                "flowfilter" => FlowFilterMode::Joint,
                "flowfilter-init-only" => FlowFilterMode::InitOnly,
                _ => FlowFilterMode::FlowOnly,
            };
            Box::new(FlowFilter::new(FlowFilterConfig { mode, ..config.flowfilter.clone() })?)
        }
        other => {
            return Err(RegistrationError::Config(format!(
                "unknown method '{other}' (available: {})",
                METHOD_NAMES.join(", ")
            )));
        }
    })
}
