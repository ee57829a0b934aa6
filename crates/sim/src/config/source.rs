//! Where a configuration's problems are: errors located by file, line and field with their
//! fix, the source text they are located in, and reading a file as text.

use std::fmt;
use std::path::Path;

/// A configuration error located in its file: what every parser of a configuration or
/// scenario file returns (this crate's segment, the lab's scenarios, the CLI's `run`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigError {
    /// File name as given.
    pub file: String,
    /// 1-based line, if known.
    pub line: Option<usize>,
    /// Dotted path of the field.
    pub field: String,
    /// What is wrong.
    pub message: String,
    /// What to do.
    pub fix: String,
}

/// The text of the file at `path`, for a parser that names lines: a file that is not UTF-8
/// is refused naming the line and column of its first bad byte (an editor's Latin-1 "é" in a
/// comment, a binary file given by mistake), not only "stream did not contain valid UTF-8".
pub fn read_text(path: &Path) -> Result<String, ConfigError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| ConfigError {
        file: file.clone(),
        line: None,
        field: "(file)".into(),
        message: format!("cannot read it: {e}"),
        fix: "give the path of a readable file".into(),
    })?;
    String::from_utf8(bytes).map_err(|e| {
        let bad = e.utf8_error().valid_up_to();
        let bytes = e.as_bytes();
        let before = &bytes[..bad];
        let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
        let line_start = before
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |i| i + 1);
        // Columns in characters: the bytes before the bad one on its line are valid UTF-8.
        let column = String::from_utf8_lossy(&before[line_start..])
            .chars()
            .count()
            + 1;
        ConfigError {
            file,
            line: Some(line),
            field: "(file)".into(),
            message: format!("byte 0x{:02X} at column {column} is not UTF-8", bytes[bad]),
            fix: "save the file as UTF-8 (TOML files are UTF-8)".into(),
        }
    })
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(l) => write!(f, "{}:{}: ", self.file, l)?,
            None => write!(f, "{}: ", self.file)?,
        }
        write!(f, "{}: {}", self.field, self.message)?;
        if !self.fix.is_empty() {
            write!(f, "; fix: {}", self.fix)?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigError {}

/// A value a file cannot be used with, before it is located: the field (its table, dotted as in
/// the file, and its key), what is wrong and what to do. [`ConfigSource::locate`] finds its line.
/// Checks that also run on values the command line changed return it, so a value is refused with
/// the same words wherever it came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The table, e.g. `run` or `methods.median`.
    pub table: String,
    /// The key in it.
    pub key: String,
    /// What is wrong.
    pub message: String,
    /// What to do.
    pub fix: String,
}

impl Problem {
    /// A problem with `key` in `table`.
    pub fn new(
        table: impl Into<String>,
        key: impl Into<String>,
        message: impl Into<String>,
        fix: impl Into<String>,
    ) -> Self {
        Problem {
            table: table.into(),
            key: key.into(),
            message: message.into(),
            fix: fix.into(),
        }
    }

    /// The dotted field.
    pub fn field(&self) -> String {
        format!("{}.{}", self.table, self.key)
    }
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}; fix: {}", self.field(), self.message, self.fix)
    }
}

/// A configuration file being parsed, its name and its text: the one place errors are located
/// (the TOML parser's, and the checks' [`Problem`]s).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConfigSource<'a> {
    /// File name as the user gave it (or the preset's name).
    pub file: &'a str,
    /// Its text.
    pub text: &'a str,
}

impl<'a> ConfigSource<'a> {
    /// The file `file` with text `text`.
    pub fn new(file: &'a str, text: &'a str) -> Self {
        ConfigSource { file, text }
    }

    /// Deserializes the text; a TOML error comes back located ([`toml_error`]).
    pub fn deserialize<T: serde::de::DeserializeOwned>(&self) -> Result<T, ConfigError> {
        toml::from_str(self.text).map_err(|e| toml_error(self.file, self.text, &e))
    }

    /// An error at a known line (or none), for a field the caller names.
    pub fn at(
        &self,
        line: Option<usize>,
        field: impl Into<String>,
        message: impl Into<String>,
        fix: impl Into<String>,
    ) -> ConfigError {
        ConfigError {
            file: self.file.to_string(),
            line,
            field: field.into(),
            message: message.into(),
            fix: fix.into(),
        }
    }

    /// The problem located in the file: the line of its `key = ...`; else the header of the
    /// table the key names (`[[table.key]]`, an array of tables, or `[table.key]`); else, for a
    /// nested table's key (`host.js.sigma_ns`, whose table may be written inline), the line of
    /// the table's key in its parent; else the table's header; else no line.
    pub fn locate(&self, p: Problem) -> ConfigError {
        let text = self.text;
        let header = |name: &str| text.find(&format!("[{name}]")).map(|at| line_of(text, at));
        let line = key_line(text, &p.table, &p.key)
            .or_else(|| {
                let sub = format!("{}.{}", p.table, p.key);
                text.find(&format!("[[{sub}]]"))
                    .map(|at| line_of(text, at))
                    .or_else(|| header(&sub))
            })
            .or_else(|| {
                let (parent, last) = p.table.rsplit_once('.')?;
                key_line(text, parent, last)
            })
            .or_else(|| header(&p.table));
        ConfigError {
            file: self.file.to_string(),
            line,
            field: p.field(),
            message: p.message,
            fix: p.fix,
        }
    }

    /// Shorthand: [`ConfigSource::locate`] of a new [`Problem`].
    pub fn error(
        &self,
        table: &str,
        key: &str,
        message: impl Into<String>,
        fix: impl Into<String>,
    ) -> ConfigError {
        self.locate(Problem::new(table, key, message, fix))
    }
}

/// The line of `key = ...` inside table `table` (dotted, as in its header), if present.
pub fn key_line(text: &str, table: &str, key: &str) -> Option<usize> {
    let mut current = String::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.starts_with('[') {
            current = l.trim_matches(['[', ']']).trim().to_string();
            continue;
        }
        if current == table
            && let Some((k, _)) = l.split_once('=')
            && k.trim() == key
        {
            return Some(i + 1);
        }
    }
    None
}

/// The line of `key = ...` in the table whose header starts at `span` (the span toml gives a
/// table of an array of tables covers its header only): the lines up to the next header.
pub(super) fn key_line_in(text: &str, span: std::ops::Range<usize>, key: &str) -> Option<usize> {
    let start = span.start.min(text.len());
    let mut at = start;
    for (k, l) in text.get(start..)?.split_inclusive('\n').enumerate() {
        if k > 0 && l.trim_start().starts_with('[') {
            break;
        }
        if k > 0
            && l.split_once('=')
                .is_some_and(|(name, _)| name.trim() == key)
        {
            return Some(line_of(text, at));
        }
        at += l.len();
    }
    None
}

/// 1-based line of a byte offset.
pub fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

/// Turns a TOML deserialisation error into a located one.
pub fn toml_error(file: &str, text: &str, e: &toml::de::Error) -> ConfigError {
    let msg = e.message().trim().to_string();
    let line = e.span().map(|s| line_of(text, s.start));
    // Name the field: the last "key" in the message, or the table header at that line.
    let field = e
        .span()
        .and_then(|s| {
            let start = text[..s.start.min(text.len())]
                .rfind('\n')
                .map_or(0, |i| i + 1);
            let l = text[start..].lines().next()?;
            let key = l.split('=').next()?.trim();
            Some(key.trim_matches(['[', ']']).to_string())
        })
        .unwrap_or_default();
    let fix = if msg.contains("unknown field") {
        "remove the field or correct its spelling (the message lists the expected fields)"
    } else if let Some(name) = msg
        .split_once("missing field `")
        .and_then(|(_, r)| r.split_once('`'))
        .map(|(n, _)| n)
    {
        return ConfigError {
            file: file.to_string(),
            line,
            field,
            fix: format!("add the field `{name}` (presets/paper-2024.toml shows every field)"),
            message: msg,
        };
    } else if let Some(expected) = msg
        .split_once("unknown variant")
        .and_then(|(_, r)| r.split_once("expected "))
        .map(|(_, e)| e.trim().trim_start_matches("one of ").trim_end_matches('.'))
    {
        // serde's "unknown variant `x`, expected `a` or `b`": the accepted values are the fix.
        return ConfigError {
            file: file.to_string(),
            line,
            field,
            fix: format!("give one of the accepted values: {expected}"),
            message: msg,
        };
    } else if msg.contains("invalid type") || msg.contains("invalid value") {
        "give a value of the type the message names"
    } else {
        "correct the TOML syntax at that line"
    };
    ConfigError {
        file: file.to_string(),
        line,
        field,
        message: msg,
        fix: fix.to_string(),
    }
}
