//! Checking a parameter set: every problem at once, each naming the schema's field, so that a
//! client fixes its request in one round trip rather than one field per try.

use std::fmt;

use thiserror::Error;

/// One parameter out of its domain; `field` is the schema's name for it.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[error("{field} must be {requirement}, got {value}")]
pub struct ParamError {
    pub field: &'static str,
    pub value: f64,
    pub requirement: &'static str,
}

/// Every problem of a parameter set, in field order; never empty.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamErrors(Vec<ParamError>);

impl ParamErrors {
    /// The first field at fault: where an error must name one field (HTTP, gRPC).
    pub fn field(&self) -> &'static str {
        self.0[0].field
    }

    pub fn problems(&self) -> &[ParamError] {
        &self.0
    }
}

impl fmt::Display for ParamErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, problem) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str("; ")?;
            }
            write!(f, "{problem}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ParamErrors {}

/// One rule of a parameter set: `field` holds `value`, which is acceptable when `ok`;
/// `requirement` says what would be, for the error.
#[derive(Debug, Clone, Copy)]
pub struct Rule {
    pub field: &'static str,
    pub value: f64,
    pub ok: bool,
    pub requirement: &'static str,
}

impl Rule {
    pub fn new(field: &'static str, value: f64, ok: bool, requirement: &'static str) -> Rule {
        Rule {
            field,
            value,
            ok,
            requirement,
        }
    }
}

/// Checks every rule; reports every one broken, in order.
pub fn check_all(rules: impl IntoIterator<Item = Rule>) -> Result<(), ParamErrors> {
    let problems: Vec<ParamError> = rules
        .into_iter()
        .filter(|r| !r.ok)
        .map(|r| ParamError {
            field: r.field,
            value: r.value,
            requirement: r.requirement,
        })
        .collect();
    if problems.is_empty() {
        Ok(())
    } else {
        Err(ParamErrors(problems))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_broken_rule_is_reported_in_order_and_the_first_names_the_field() {
        let e = check_all([
            Rule::new("a", 1.0, true, "anything"),
            Rule::new("b", -1.0, false, "at least 0"),
            Rule::new("c", f64::NAN, false, "a finite number"),
        ])
        .unwrap_err();
        assert_eq!(e.field(), "b");
        assert_eq!(e.problems().len(), 2);
        assert_eq!(
            e.to_string(),
            "b must be at least 0, got -1; c must be a finite number, got NaN"
        );
        assert!(check_all([Rule::new("a", 1.0, true, "anything")]).is_ok());
    }
}
