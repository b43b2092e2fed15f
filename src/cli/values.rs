//! Parsers of command-line values that refuse what has no meaning (clap's
//! `value_parser`): the message names the value and what it must be (clap adds the
//! option's name).

/// Why a command-line value has no meaning.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BadArgument {
    #[error("{0:?} is not a number")]
    NotANumber(String),
    #[error("{0:?} is not a whole number")]
    NotWhole(String),
    #[error("must be a finite number, got {0}")]
    NotFinite(f64),
    #[error("must not be negative, got {0}")]
    Negative(f64),
    #[error("must be in [0, 1], got {0}")]
    NotAFraction(f64),
    #[error("must be at least {least}, got {got}")]
    TooSmall { least: usize, got: usize },
}

/// A finite number (no NaN, no infinity).
pub fn finite(text: &str) -> Result<f64, BadArgument> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(BadArgument::NotFinite(v)),
        Err(_) => Err(BadArgument::NotANumber(text.to_string())),
    }
}

/// A finite number, 0 or more.
pub fn non_negative(text: &str) -> Result<f64, BadArgument> {
    let v = finite(text)?;
    if v < 0.0 {
        return Err(BadArgument::Negative(v));
    }
    Ok(v)
}

/// A fraction in [0, 1].
pub fn fraction(text: &str) -> Result<f64, BadArgument> {
    let v = finite(text)?;
    if !(0.0..=1.0).contains(&v) {
        return Err(BadArgument::NotAFraction(v));
    }
    Ok(v)
}

fn count_from(text: &str, least: usize) -> Result<usize, BadArgument> {
    match text.trim().parse::<usize>() {
        Ok(got) if got >= least => Ok(got),
        Ok(got) => Err(BadArgument::TooSmall { least, got }),
        Err(_) => Err(BadArgument::NotWhole(text.to_string())),
    }
}

/// A whole number, 1 or more.
pub fn at_least_one(text: &str) -> Result<usize, BadArgument> {
    count_from(text, 1)
}

/// A whole number, 2 or more.
pub fn at_least_two(text: &str) -> Result<usize, BadArgument> {
    count_from(text, 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_what_has_no_meaning() {
        assert!(finite("nan").is_err() && finite("inf").is_err());
        assert_eq!(finite("x"), Err(BadArgument::NotANumber("x".into())));
        assert_eq!(finite("-0.5"), Ok(-0.5));
        assert_eq!(non_negative("-1"), Err(BadArgument::Negative(-1.0)));
        assert!(fraction("nan").is_err() && fraction("1.5").is_err());
        assert_eq!(fraction("0.25"), Ok(0.25));
        assert!(at_least_one("0").is_err());
        assert_eq!(
            at_least_two("1"),
            Err(BadArgument::TooSmall { least: 2, got: 1 })
        );
        assert_eq!(at_least_two("2"), Ok(2));
    }
}
