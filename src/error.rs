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
