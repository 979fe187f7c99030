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

impl InputError {
    /// The one line of `Display`, with the options that message and fix name as `$key`
    /// (`pass $motion discrete`) spelled by `spell`, as each shell words them (see
    /// [`OptionError`]).
    pub fn worded(&self, spell: impl Fn(OptionKey) -> String) -> String {
        let mut out = self.file.display().to_string();
        if let Some(line) = self.line {
            out += &format!(":{line}");
        }
        out += ": ";
        if let Some(column) = &self.column {
            out += &format!("{column}: ");
        }
        out += &format!(
            "{} (fix: {})",
            word(&self.message, &spell),
            word(&self.fix, &spell)
        );
        out
    }
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.worded(|k| k.name().to_string()))
    }
}

impl std::error::Error for InputError {}

/// An option of a run, a watch or a verification, by the library's own name. Each shell words
/// it in its own terms: `--delta` on the command line, `"delta"` in job.json, a panel field in
/// the add-on. [`OptionKey::name`] is the job.json key where the option has one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OptionKey {
    Resolution,
    Tolerance,
    Delta,
    Epsilon,
    Name,
    Out,
    Overwrite,
    NoMemoryCheck,
    Spacing,
    Bound,
    Settle,
    Rescan,
    Motion,
    Classify,
    Backend,
    Radii,
    MaxInputBytes,
    TargetTriangles,
    KeepStartMesh,
    Also,
    Against,
    RequireClearance,
    ClearanceScale,
    RelativeTo,
    Rows,
    PackageDir,
}

impl OptionKey {
    pub const ALL: [OptionKey; 26] = [
        OptionKey::Resolution,
        OptionKey::Tolerance,
        OptionKey::Delta,
        OptionKey::Epsilon,
        OptionKey::Name,
        OptionKey::Out,
        OptionKey::Overwrite,
        OptionKey::NoMemoryCheck,
        OptionKey::Spacing,
        OptionKey::Bound,
        OptionKey::Settle,
        OptionKey::Rescan,
        OptionKey::Motion,
        OptionKey::Classify,
        OptionKey::Backend,
        OptionKey::Radii,
        OptionKey::MaxInputBytes,
        OptionKey::TargetTriangles,
        OptionKey::KeepStartMesh,
        OptionKey::Also,
        OptionKey::Against,
        OptionKey::RequireClearance,
        OptionKey::ClearanceScale,
        OptionKey::RelativeTo,
        OptionKey::Rows,
        OptionKey::PackageDir,
    ];

    /// The library's name: snake_case, the same as the job.json key where there is one.
    pub fn name(self) -> &'static str {
        match self {
            OptionKey::Resolution => "resolution",
            OptionKey::Tolerance => "tolerance",
            OptionKey::Delta => "delta",
            OptionKey::Epsilon => "epsilon",
            OptionKey::Name => "name",
            OptionKey::Out => "out",
            OptionKey::Overwrite => "overwrite",
            OptionKey::NoMemoryCheck => "no_memory_check",
            OptionKey::Spacing => "spacing",
            OptionKey::Bound => "bound",
            OptionKey::Settle => "settle",
            OptionKey::Rescan => "rescan",
            OptionKey::Motion => "motion",
            OptionKey::Classify => "classify",
            OptionKey::Backend => "backend",
            OptionKey::Radii => "radii",
            OptionKey::MaxInputBytes => "max_input_bytes",
            OptionKey::TargetTriangles => "target_triangles",
            OptionKey::KeepStartMesh => "keep_start_mesh",
            OptionKey::Also => "also",
            OptionKey::Against => "against",
            OptionKey::RequireClearance => "require_clearance",
            OptionKey::ClearanceScale => "clearance_scale",
            OptionKey::RelativeTo => "relative_to",
            OptionKey::Rows => "rows",
            OptionKey::PackageDir => "package_dir",
        }
    }

    /// The command line's spelling: `--no-memory-check`.
    pub fn flag(self) -> String {
        format!("--{}", self.name().replace('_', "-"))
    }
}

/// A bad option value or combination (`--resolution 4`, `--tolerance -1`, an output name equal
/// to an input): exit code 2 like an [`InputError`], with what is wrong and what to do.
///
/// `key` is the option at fault. The text names options as `$key` placeholders (`$delta`,
/// `$no_memory_check`), so that [`OptionError::worded`] can spell them as the shell the user
/// typed them in does; `Display` uses the library's plain names ("delta must exceed ε + σ").
#[derive(Debug, Clone, PartialEq)]
pub struct OptionError {
    pub key: OptionKey,
    template: String,
}

impl OptionError {
    /// `template` names options as `$key` (see the type's comment).
    pub fn new(key: OptionKey, template: impl Into<String>) -> Self {
        let template = template.into();
        OptionError { key, template }
    }

    /// The text with each `$key` spelled by `spell` (`OptionKey::flag` for the CLI).
    pub fn worded(&self, spell: impl Fn(OptionKey) -> String) -> String {
        word(&self.template, spell)
    }
}

/// `template` with each `$key` that names an option spelled by `spell`; a `$` that names none
/// stays as written. The library words its text this way, never with a shell's flags.
pub fn word(template: &str, spell: impl Fn(OptionKey) -> String) -> String {
    let mut out = String::with_capacity(template.len());
    let mut rest = template;
    while let Some(i) = rest.find('$') {
        out.push_str(&rest[..i]);
        let after = &rest[i + 1..];
        let len = after
            .find(|c: char| !(c.is_ascii_lowercase() || c == '_'))
            .unwrap_or(after.len());
        match OptionKey::ALL.iter().find(|k| k.name() == &after[..len]) {
            Some(&k) => out.push_str(&spell(k)),
            None => out.push_str(&rest[i..i + 1 + len]),
        }
        rest = &after[len..];
    }
    out.push_str(rest);
    out
}

/// `template` in the library's own words: each `$key` as its plain name (`motion`), as text
/// that no one shell owns (report.json) reads it.
pub fn plain(template: &str) -> String {
    word(template, |k| k.name().to_string())
}

impl fmt::Display for OptionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.worded(|k| k.name().to_string()))
    }
}

impl std::error::Error for OptionError {}

/// An error chain as `{:#}` prints it, with the options that option and input errors name
/// spelled by `spell` (the command line's flags, the watcher's job.json keys).
pub fn worded_chain(e: &anyhow::Error, spell: impl Fn(OptionKey) -> String) -> String {
    let parts: Vec<String> = e
        .chain()
        .map(|c| {
            if let Some(o) = c.downcast_ref::<OptionError>() {
                o.worded(&spell)
            } else if let Some(i) = c.downcast_ref::<InputError>() {
                i.worded(&spell)
            } else {
                c.to_string()
            }
        })
        .collect();
    parts.join(": ")
}

/// Exit code 2 errors: a problem with an input file or an option value.
pub fn is_user_error(e: &anyhow::Error) -> bool {
    e.chain()
        .any(|c| c.is::<InputError>() || c.is::<OptionError>())
}

/// A number for a message: plain notation in a sane range, else scientific (never 300 digits).
pub fn num(x: f64) -> String {
    if x == 0.0 || (1e-4..1e7).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn option_errors_are_worded_by_each_shell() {
        let e = OptionError::new(
            OptionKey::Delta,
            "δ = 0.1 must exceed ε + σ; raise $delta or lower $epsilon, or pass $no_memory_check",
        );
        assert_eq!(
            e.to_string(),
            "δ = 0.1 must exceed ε + σ; raise delta or lower epsilon, or pass no_memory_check"
        );
        assert_eq!(
            e.worded(OptionKey::flag),
            "δ = 0.1 must exceed ε + σ; raise --delta or lower --epsilon, or pass --no-memory-check"
        );
        assert_eq!(e.key, OptionKey::Delta);
        // A `$` that names no option stays as written.
        let plain = OptionError::new(OptionKey::Name, "costs $5 or $x_unknown");
        assert_eq!(plain.worded(OptionKey::flag), "costs $5 or $x_unknown");
    }

    #[test]
    fn option_names_are_distinct() {
        let names: std::collections::HashSet<_> = OptionKey::ALL.iter().map(|k| k.name()).collect();
        assert_eq!(names.len(), OptionKey::ALL.len());
    }
}
