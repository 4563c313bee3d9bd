//! Structured log lines (logfmt) on standard error: one event per line, `key=value` pairs a
//! log collector or `grep` can take apart, e.g.
//!
//! `ts=1763721000.123 level=info event=ready domain=default clock=simulation pid=4242`
//!
//! The controller logs state changes only (start, episodes, silences, stop), never per tick.

use std::fmt::{self, Display, Write as _};
use std::io::Write as _;
use std::time::{SystemTime, UNIX_EPOCH};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Level {
    Info,
    Warn,
    Error,
}

impl Level {
    fn as_str(self) -> &'static str {
        match self {
            Self::Info => "info",
            Self::Warn => "warn",
            Self::Error => "error",
        }
    }
}

/// Formats one event as a logfmt line (without the time stamp).
pub fn format_event(level: Level, event: &str, fields: &[(&str, &dyn Display)]) -> String {
    let mut line = format!("level={} event={}", level.as_str(), event);
    for (key, value) in fields {
        let _ = write!(line, " {key}=");
        push_value(&mut line, value);
    }
    line
}

fn push_value(line: &mut String, value: &dyn Display) {
    let text = value.to_string();
    let plain = !text.is_empty()
        && text
            .chars()
            .all(|c| !c.is_whitespace() && c != '"' && c != '=' && !c.is_control());
    if plain {
        line.push_str(&text);
    } else {
        let _ = write!(line, "{text:?}");
    }
}

/// Writes one event to standard error, stamped with the wall-clock time.
pub fn log(level: Level, event: &str, fields: &[(&str, &dyn Display)]) {
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default();
    let line = format_event(level, event, fields);
    let _ = writeln!(
        std::io::stderr().lock(),
        "ts={}.{:03} {line}",
        now.as_secs(),
        now.subsec_millis()
    );
}

/// Displays an error with its causes on one line.
#[derive(Debug)]
pub struct Chain<'a>(pub &'a (dyn std::error::Error + 'static));

impl Display for Chain<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)?;
        let mut source = self.0.source();
        while let Some(cause) = source {
            write!(f, ": {cause}")?;
            source = cause.source();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_with_spaces_or_quotes_are_quoted() {
        let line = format_event(
            Level::Warn,
            "silent",
            &[("ms", &100), ("why", &"no tick \"here\""), ("empty", &"")],
        );
        assert_eq!(
            line,
            r#"level=warn event=silent ms=100 why="no tick \"here\"" empty="""#
        );
    }
}
