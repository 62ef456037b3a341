//! Value parsers shared by the subcommands' arguments: numbers that must be finite or
//! positive, and turntable angles.

/// A finite number (`nan` and `inf` parse as floats; no argument means either).
pub fn finite_f64(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if v.is_finite() { Ok(v) } else { Err(format!("must be a finite number, found {v}")) }
}

/// A finite `f32` (the synthesiser's offsets).
pub fn finite_f32(s: &str) -> Result<f32, String> {
    let v = finite_f64(s)?;
    if v.abs() <= f64::from(f32::MAX) { Ok(v as f32) } else { Err(format!("{v} is out of range")) }
}

/// Two finite numbers `a,b` (the synthesiser's table offset `dx,dy`).
pub fn offset_pair(s: &str) -> Result<[f32; 2], String> {
    match s.split(',').map(finite_f32).collect::<Result<Vec<_>, _>>()?.as_slice() {
        [a, b] => Ok([*a, *b]),
        v => Err(format!("expected two numbers `dx,dy`, found {}", v.len())),
    }
}

/// A finite number > 0.
pub fn positive_f64(s: &str) -> Result<f64, String> {
    let v = finite_f64(s)?;
    if v > 0.0 { Ok(v) } else { Err(format!("must be > 0, found {v}")) }
}

/// A turntable angle: whole degrees in 0..360.
pub fn turntable_angle(s: &str) -> Result<u32, String> {
    let v: i64 = s.trim().parse().map_err(|_| format!("'{s}' is not a whole number of degrees"))?;
    match u32::try_from(v) {
        Ok(a) if a < 360 => Ok(a),
        _ if v < 0 => Err(format!(
            "turntable angles are whole degrees in 0..360, found {v} (the same angle is {})",
            v.rem_euclid(360)
        )),
        _ => Err(format!("turntable angles are whole degrees in 0..360, found {v}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parsers_reject_what_no_argument_means() {
        assert!(finite_f64("nan").is_err() && finite_f64("-inf").is_err() && finite_f64("x").is_err());
        assert_eq!(finite_f64("-0.5"), Ok(-0.5));
        assert!(positive_f64("0").is_err() && positive_f64("1e-3").is_ok());
        assert!(finite_f32("1e300").is_err());
        assert_eq!(offset_pair("-0.01,0.02"), Ok([-0.01, 0.02]));
        assert!(offset_pair("nan,0").is_err() && offset_pair("0.1").is_err());
        assert_eq!(turntable_angle("357"), Ok(357));
        assert!(turntable_angle("-3").unwrap_err().contains("357"));
        assert!(turntable_angle("360").is_err() && turntable_angle("1.5").is_err());
    }
}
