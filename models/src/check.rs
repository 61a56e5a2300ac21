//! Configuration checks that name the field and the fix.
//!
//! Every configuration struct in the workspace (the daemon's, the sensor
//! descriptions here, the simulator's) validates itself through [`Validate`]
//! and reports a [`FieldError`], so a user always reads which field is wrong
//! and what to set instead.

/// A configuration value that is wrong, with the field's full name and how to
/// fix it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("config field `{field}`: {problem}; {fix}")]
pub struct FieldError {
    pub field: String,
    pub problem: String,
    pub fix: String,
}

/// Range checks that name the field.
pub struct Check<'a> {
    prefix: &'a str,
}

impl<'a> Check<'a> {
    pub fn new(prefix: &'a str) -> Self {
        Self { prefix }
    }
    fn name(&self, field: &str) -> String {
        if self.prefix.is_empty() {
            field.to_string()
        } else {
            format!("{}.{}", self.prefix, field)
        }
    }
    /// `lo ≤ v ≤ hi` and finite.
    pub fn range(&self, field: &str, v: f64, lo: f64, hi: f64) -> Result<(), FieldError> {
        if !v.is_finite() {
            return Err(FieldError {
                field: self.name(field),
                problem: format!("{v} is not a finite number"),
                fix: format!("set a number between {lo} and {hi}"),
            });
        }
        if v < lo || v > hi {
            return Err(FieldError {
                field: self.name(field),
                problem: format!("{v} is out of range"),
                fix: format!("set a value between {lo} and {hi}"),
            });
        }
        Ok(())
    }
    /// `lo < v ≤ hi` and finite.
    pub fn positive(&self, field: &str, v: f64, hi: f64) -> Result<(), FieldError> {
        self.range(field, v, 0.0, hi)?;
        if v <= 0.0 {
            return Err(FieldError {
                field: self.name(field),
                problem: format!("{v} must be greater than zero"),
                fix: format!("set a value in (0, {hi}]"),
            });
        }
        Ok(())
    }
    /// `lo ≤ v ≤ hi` for a count, a size or an id; `fix` says what to set.
    pub fn within(&self, field: &str, v: u64, lo: u64, hi: u64, fix: &str) -> Result<(), FieldError> {
        if (lo..=hi).contains(&v) {
            Ok(())
        } else {
            Err(self.fail(field, format!("{v} is out of range"), fix))
        }
    }
    pub fn all_finite(&self, field: &str, v: &[f64], lo: f64, hi: f64) -> Result<(), FieldError> {
        for (i, x) in v.iter().enumerate() {
            self.range(&format!("{field}[{i}]"), *x, lo, hi)?;
        }
        Ok(())
    }
    pub fn fail(&self, field: &str, problem: impl Into<String>, fix: impl Into<String>) -> FieldError {
        FieldError {
            field: self.name(field),
            problem: problem.into(),
            fix: fix.into(),
        }
    }
}

/// Anything that can check its own values.
pub trait Validate {
    fn validate(&self, prefix: &str) -> Result<(), FieldError>;
}
