//! A policy kind on a command line.

use crate::config::PolicyKind;

/// Parses a policy kind on a command line by its name and lists every kind with its summary in `--help`: what
/// clap's `ValueEnum` derive would give, kept here so the checkpoint format's crate needs no clap.
pub fn policy_kind_parser() -> impl clap::builder::TypedValueParser<Value = PolicyKind> {
    use clap::builder::TypedValueParser;
    let values = PolicyKind::ALL.map(|k| clap::builder::PossibleValue::new(k.name()).help(k.summary()));
    clap::builder::PossibleValuesParser::new(values).try_map(|s| s.parse::<PolicyKind>())
}
