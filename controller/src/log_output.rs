//! Where log events go: `tracing` events on standard error, one line each, as logfmt through
//! `tracing-logfmt` or as JSON through `tracing-subscriber`, filtered by `RUST_LOG` (default
//! `info`), e.g.
//!
//! `ts=2026-11-23T12:00:00.123456Z level=info event=ready domain=default clock=simulation`
//!
//! Each event names itself in an `event` field (`ready`, `episode`, `cameras_silent`, ...) so
//! that a log collector or `grep event=ready` finds it whatever the format. The controller logs
//! state changes only (start, episodes, silences, stop), never per tick: formatting an event
//! allocates, so no `tracing` call sits on the tick's path (`tests/tick_allocations.rs` runs
//! with this subscriber installed).

use std::fmt;
use std::str::FromStr;

use tracing_subscriber::EnvFilter;
use tracing_subscriber::layer::SubscriberExt as _;
use tracing_subscriber::util::SubscriberInitExt as _;

/// The line format of the log on standard error.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LogFormat {
    /// `key=value` pairs (logfmt): readable, and `grep`-able by field.
    #[default]
    Logfmt,
    /// One JSON object per line, for log collectors.
    Json,
}

impl LogFormat {
    pub const NAMES: [&str; 2] = ["logfmt", "json"];
}

impl fmt::Display for LogFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Logfmt => "logfmt",
            Self::Json => "json",
        })
    }
}

impl FromStr for LogFormat {
    type Err = LogSetupError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        match name {
            "logfmt" => Ok(Self::Logfmt),
            "json" => Ok(Self::Json),
            other => Err(LogSetupError::UnknownFormat(other.to_owned())),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum LogSetupError {
    #[error("unknown log format {0:?} (known: logfmt, json)")]
    UnknownFormat(String),
    #[error("RUST_LOG={value:?} is not a filter `tracing` understands: {reason}")]
    BadFilter { value: String, reason: String },
    #[error("a log subscriber is already installed in this process")]
    AlreadyInstalled,
}

/// The filter `RUST_LOG` asks for, `info` where it is unset or empty.
fn filter_from_env() -> Result<EnvFilter, LogSetupError> {
    match std::env::var(EnvFilter::DEFAULT_ENV) {
        Ok(value) if !value.trim().is_empty() => parse_filter(&value),
        _ => Ok(EnvFilter::new("info")),
    }
}

/// `directives` in `RUST_LOG`'s syntax, or why not.
fn parse_filter(directives: &str) -> Result<EnvFilter, LogSetupError> {
    EnvFilter::try_new(directives).map_err(|error| LogSetupError::BadFilter {
        value: directives.to_owned(),
        reason: error.to_string(),
    })
}

/// Installs the process's log subscriber: `format` lines on standard error, filtered by
/// `RUST_LOG`. Call once, first thing in `main`.
pub fn install(format: LogFormat) -> Result<(), LogSetupError> {
    install_filtered(format, filter_from_env()?)
}

/// Installs the process's log subscriber with the filter `directives` in `RUST_LOG`'s
/// syntax instead of the environment's (the allocation tests use `trace`, so that any event
/// on the tick's path would be formatted, and counted).
pub fn install_with_filter(format: LogFormat, directives: &str) -> Result<(), LogSetupError> {
    install_filtered(format, parse_filter(directives)?)
}

fn install_filtered(format: LogFormat, filter: EnvFilter) -> Result<(), LogSetupError> {
    let registry = tracing_subscriber::registry().with(filter);
    let installed = match format {
        LogFormat::Logfmt => registry
            .with(
                tracing_logfmt::builder()
                    .with_target(false)
                    .layer()
                    .with_writer(std::io::stderr),
            )
            .try_init(),
        LogFormat::Json => registry
            .with(
                tracing_subscriber::fmt::layer()
                    .json()
                    .flatten_event(true)
                    .with_target(false)
                    .with_writer(std::io::stderr),
            )
            .try_init(),
    };
    installed.map_err(|_| LogSetupError::AlreadyInstalled)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_parse_from_their_names_and_print_them_back() {
        for name in LogFormat::NAMES {
            let format: LogFormat = name.parse().expect("known name");
            assert_eq!(format.to_string(), name);
        }
        assert!(matches!(
            "yaml".parse::<LogFormat>(),
            Err(LogSetupError::UnknownFormat(name)) if name == "yaml"
        ));
    }
}
