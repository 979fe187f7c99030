//! Errors about user input: every one names the file, where in it, what is wrong and how to fix it.

use std::fmt;
use std::path::{Path, PathBuf};

/// A problem with an input file. `Display` gives one line a person can act on:
/// `part.csv:12: qw: quaternion has norm 0.5 (fix: write a unit quaternion ...)`.
#[derive(Debug, Clone, PartialEq)]
pub struct InputError {
    pub file: PathBuf,
    /// 1-based line in a text file (CSV), if the problem has one.
    pub line: Option<u64>,
    /// Column name (CSV) or JSON path / object name (glTF), if the problem has one.
    pub column: Option<String>,
    pub message: String,
    /// What the user should do about it.
    pub fix: String,
}

impl InputError {
    pub fn new(file: &Path, message: impl Into<String>, fix: impl Into<String>) -> Self {
        InputError {
            file: file.to_path_buf(),
            line: None,
            column: None,
            message: message.into(),
            fix: fix.into(),
        }
    }

    pub fn at_line(mut self, line: u64) -> Self {
        self.line = Some(line);
        self
    }

    pub fn in_column(mut self, column: impl Into<String>) -> Self {
        self.column = Some(column.into());
        self
    }
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        write!(f, ": ")?;
        if let Some(column) = &self.column {
            write!(f, "{column}: ")?;
        }
        write!(f, "{} (fix: {})", self.message, self.fix)
    }
}

impl std::error::Error for InputError {}

/// A bad option value or combination (`--resolution 4`, `--tolerance -1`, an output name equal
/// to an input): exit code 2 like an [`InputError`], with what is wrong and what to do.
#[derive(Debug, Clone, PartialEq)]
pub struct UsageError {
    pub message: String,
}

impl UsageError {
    pub fn new(message: impl Into<String>) -> Self {
        UsageError {
            message: message.into(),
        }
    }
}

impl fmt::Display for UsageError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for UsageError {}

/// Exit code 2 errors: a problem with an input file or an option value.
pub fn is_user_error(e: &anyhow::Error) -> bool {
    e.chain()
        .any(|c| c.is::<InputError>() || c.is::<UsageError>())
}

/// A number for a message: plain notation in a sane range, else scientific (never 300 digits).
pub fn num(x: f64) -> String {
    if x == 0.0 || (1e-4..1e7).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}
