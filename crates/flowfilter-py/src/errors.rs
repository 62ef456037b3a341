//! The exception hierarchy (`flowfilter.Error`, `InputError`, `ConfigError`) and the mapping of
//! the library's typed errors onto it; the message is the Rust message.

use flowfilter_pipeline::{FlowError, PipelineError, RegistrationError};
use pyo3::PyErr;
use pyo3::create_exception;
use pyo3::exceptions::PyException;

create_exception!(
    flowfilter,
    Error,
    PyException,
    "Base of every error flowfilter raises; the message names the array, file or key at fault."
);
create_exception!(
    flowfilter,
    InputError,
    Error,
    "An array, file or frame that cannot be used: wrong shape or dtype, NaN, empty, sizes that disagree."
);
create_exception!(
    flowfilter,
    ConfigError,
    Error,
    "A method name, parameter or configuration value that is unknown or out of range."
);

/// An [`InputError`] with `message`.
pub fn input(message: impl Into<String>) -> PyErr {
    InputError::new_err(message.into())
}

/// A [`ConfigError`] with `message`.
pub fn config(message: impl Into<String>) -> PyErr {
    ConfigError::new_err(message.into())
}

/// The error's message followed by each cause that it does not already contain.
pub fn message(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let part = c.to_string();
        if !text.contains(&part) {
            text = format!("{text}: {part}");
        }
        cause = c.source();
    }
    text
}

/// A registration error as the exception a caller can act on.
pub fn registration(e: &RegistrationError) -> PyErr {
    let text = message(e);
    match e {
        RegistrationError::Config(_) => config(text),
        RegistrationError::MissingNormals { which, .. } => {
            input(format!("{text} (pass {which}_normals=..., e.g. flowfilter.estimate_normals({which}))"))
        }
        _ => input(text),
    }
}

/// A flow error as the exception a caller can act on.
pub fn flow(e: &FlowError) -> PyErr {
    match e {
        FlowError::Config(_) => config(message(e)),
        FlowError::Model { .. } => Error::new_err(message(e)),
        _ => input(message(e)),
    }
}

/// A pipeline error as the exception a caller can act on.
pub fn pipeline(e: &PipelineError) -> PyErr {
    match e {
        PipelineError::Config { .. } => config(message(e)),
        PipelineError::Registration(r @ RegistrationError::Config(_)) => {
            config(format!("registration: {}", message(r)))
        }
        PipelineError::Flow(FlowError::Config(_)) => config(message(e)),
        PipelineError::Flow(FlowError::Model { .. }) => Error::new_err(message(e)),
        _ => input(message(e)),
    }
}
