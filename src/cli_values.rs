//! Parsers of command-line values that refuse what has no meaning (clap's
//! `value_parser`): the message names the value and what it must be.

/// A finite number (no NaN, no infinity).
pub fn finite(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(format!("must be a finite number, got {v}")),
        Err(_) => Err(format!("{text:?} is not a number")),
    }
}

/// A finite number, 0 or more.
pub fn non_negative(text: &str) -> Result<f64, String> {
    let v = finite(text)?;
    if v < 0.0 {
        return Err(format!("must not be negative, got {v}"));
    }
    Ok(v)
}

/// A fraction in [0, 1].
pub fn fraction(text: &str) -> Result<f64, String> {
    let v = finite(text)?;
    if !(0.0..=1.0).contains(&v) {
        return Err(format!("must be in [0, 1], got {v}"));
    }
    Ok(v)
}

fn count_from(text: &str, least: usize) -> Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(n) if n >= least => Ok(n),
        Ok(n) => Err(format!("must be at least {least}, got {n}")),
        Err(_) => Err(format!("{text:?} is not a whole number")),
    }
}

/// A whole number, 1 or more.
pub fn at_least_one(text: &str) -> Result<usize, String> {
    count_from(text, 1)
}

/// A whole number, 2 or more.
pub fn at_least_two(text: &str) -> Result<usize, String> {
    count_from(text, 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_what_has_no_meaning() {
        assert!(finite("nan").is_err() && finite("inf").is_err() && finite("x").is_err());
        assert_eq!(finite("-0.5"), Ok(-0.5));
        assert!(non_negative("-1").is_err());
        assert!(fraction("nan").is_err() && fraction("1.5").is_err());
        assert_eq!(fraction("0.25"), Ok(0.25));
        assert!(at_least_one("0").is_err() && at_least_two("1").is_err());
        assert_eq!(at_least_two("2"), Ok(2));
    }
}
