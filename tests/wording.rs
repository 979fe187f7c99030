//! Issue 27, "flags leak to people who never typed one": the library names options as `$key`
//! templates (`error::word`), and each shell spells them: the command line as flags
//! (tests/hostile.rs), the watcher as job.json keys (tests/watch.rs), report.json by their
//! plain names. This test holds the library's string literals to it: none outside the places
//! below names a command-line flag.

use std::fs;
use std::path::Path;

/// Where a flag may be spelled, and why.
const ALLOWED: [(&str, &str); 6] = [
    ("src/main.rs", "the command line itself"),
    (
        "src/cluster/",
        "writes the sbatch scripts and the array tasks' command lines",
    ),
    (
        "src/pipeline/shard.rs",
        "texts of `sweep --shard` and `mesh --from`, which only the command line runs",
    ),
    (
        "src/io/shard_files.rs",
        "the shard files' errors, which only `sweep --shard` and `mesh --from` meet",
    ),
    (
        "src/verify/",
        "texts of `verify`, which only the command line runs",
    ),
    (
        "src/watch/daemon.rs",
        "the daemon's log lines about its own flags",
    ),
];

/// The string literals of Rust source `s` (comments, char literals and the `tests` module left
/// out), each with its line.
fn literals(s: &str) -> Vec<(usize, String)> {
    let s = match s.find("#[cfg(test)]\nmod tests") {
        Some(i) => &s[..i],
        None => s,
    };
    let b = s.as_bytes();
    let (mut out, mut i, mut line) = (Vec::new(), 0, 1);
    while i < b.len() {
        match b[i] {
            b'\n' => line += 1,
            b'/' if b.get(i + 1) == Some(&b'/') => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
                continue;
            }
            b'\'' if b.get(i + 1) == Some(&b'\\') => {
                i += 2;
                while i < b.len() && b[i] != b'\'' {
                    i += 1;
                }
            }
            b'\'' if b.get(i + 2) == Some(&b'\'') => i += 2,
            b'"' => {
                let (start, at) = (i + 1, line);
                i += 1;
                while i < b.len() && b[i] != b'"' {
                    if b[i] == b'\\' {
                        i += 1;
                    }
                    if b[i] == b'\n' {
                        line += 1;
                    }
                    i += 1;
                }
                out.push((at, s[start..i].to_string()));
            }
            _ => {}
        }
        i += 1;
    }
    out
}

/// Whether `text` holds a flag: `--` and a letter, not inside a word or a longer dash run.
fn names_a_flag(text: &str) -> bool {
    let b = text.as_bytes();
    (0..b.len().saturating_sub(2)).any(|i| {
        b[i] == b'-'
            && b[i + 1] == b'-'
            && b[i + 2].is_ascii_lowercase()
            && (i == 0 || !(b[i - 1] == b'-' || b[i - 1].is_ascii_alphanumeric()))
    })
}

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn the_library_names_no_command_line_flag() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    files.sort();
    let mut found = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(root).unwrap().to_string_lossy().into_owned();
        if ALLOWED.iter().any(|(p, _)| rel.starts_with(p)) {
            continue;
        }
        for (line, text) in literals(&fs::read_to_string(f).unwrap()) {
            if names_a_flag(&text) {
                found.push(format!("{rel}:{line}: {text}"));
            }
        }
    }
    assert!(
        found.is_empty(),
        "library text that names a flag (word the option as $key instead):\n{}",
        found.join("\n")
    );
    // The scanner itself finds what it must.
    let sample =
        "let a = '\"'; // \"--not\"\nlet b = \"pass --motion discrete\";\nlet c = \"a--b ---x\";";
    let hits: Vec<_> = literals(sample)
        .into_iter()
        .filter(|(_, t)| names_a_flag(t))
        .collect();
    assert_eq!(hits, [(2, "pass --motion discrete".to_string())]);
}
