//! Small helpers shared by the text formats: reading a file's lines, parsing whitespace-separated
//! numbers with errors that name the file and line, and C-style `%.12e` formatting.

use crate::error::{Error, Result};
use std::path::Path;

/// Reads a text file; errors name the file.
pub(crate) fn read_to_string(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        Error::bad_input(
            path,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}

/// Parses every whitespace-separated token of `s` as f64. `line_no` is 1-based, for errors.
pub(crate) fn parse_numbers(path: &Path, line_no: usize, s: &str) -> Result<Vec<f64>> {
    s.split_whitespace()
        .map(|t| {
            t.parse::<f64>().map_err(|_| {
                Error::bad_input(path, format!("line {line_no}: '{t}' is not a number"))
            })
        })
        .collect()
}

/// Parses exactly `n` numbers from `s`.
pub(crate) fn parse_n(path: &Path, line_no: usize, s: &str, n: usize) -> Result<Vec<f64>> {
    let v = parse_numbers(path, line_no, s)?;
    if v.len() != n {
        return Err(Error::bad_input(
            path,
            format!("line {line_no}: expected {n} numbers, found {}", v.len()),
        ));
    }
    Ok(v)
}

/// Formats like C's `%.{digits}e`: `7.188560000000e+02`, `-1.5e-03`, exponent with a sign and
/// at least two digits. Non-finite values print as `nan`, `inf`, `-inf`.
pub(crate) fn fmt_e(x: f64, digits: usize) -> String {
    if !x.is_finite() {
        return if x.is_nan() {
            "nan".into()
        } else if x > 0.0 {
            "inf".into()
        } else {
            "-inf".into()
        };
    }
    let s = format!("{x:.digits$e}");
    match s.split_once('e') {
        Some((mantissa, exp)) => {
            let exp: i32 = exp.parse().unwrap_or(0);
            let sign = if exp < 0 { '-' } else { '+' };
            format!("{mantissa}e{sign}{:02}", exp.abs())
        }
        None => s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn c_style_exponent() {
        assert_eq!(fmt_e(718.856, 12), "7.188560000000e+02");
        assert_eq!(fmt_e(-0.0011, 3), "-1.100e-03");
        assert_eq!(fmt_e(0.0, 2), "0.00e+00");
        assert_eq!(fmt_e(1e123, 1), "1.0e+123");
        assert_eq!("7.188560000000e+02".parse::<f64>().unwrap(), 718.856);
    }
}
