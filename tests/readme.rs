//! The README's commands (issue #31): every command line in its `sh` code blocks that runs one
//! of the tools is accepted by that tool's parser (run with `NIMBUS_PARSE_ONLY`, as
//! tests/help.rs runs the help's examples), and the demo commands it shows are the ones
//! scripts/demo.sh runs, tool for tool and flag for flag, so the two cannot drift apart.

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::{parse_only, scratch, TOOLS};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn readme() -> String {
    std::fs::read_to_string(root().join("README.md")).unwrap()
}

/// The command lines of the markdown's ```sh code blocks: continuation lines (ending in `\`)
/// joined, blank lines and comments (` #` to the end of the line) dropped.
fn commands(markdown: &str) -> Vec<String> {
    let mut commands = Vec::new();
    let mut in_sh = false;
    let mut current = String::new();
    for line in markdown.lines() {
        if line.starts_with("```") {
            in_sh = !in_sh && line.trim_end() == "```sh";
            continue;
        }
        if !in_sh {
            continue;
        }
        let line = line.split(" #").next().unwrap().trim();
        match line.strip_suffix('\\') {
            Some(part) => current.push_str(part),
            None => {
                current.push_str(line);
                if !current.trim().is_empty() {
                    commands.push(current.split_whitespace().collect::<Vec<_>>().join(" "));
                }
                current.clear();
            }
        }
    }
    commands
}

/// The segments of a pipeline that run one of the tools.
fn tool_segments(command: &str) -> Vec<&str> {
    command.split(" | ").map(str::trim).filter(|s| TOOLS.contains(&s.split_whitespace().next().unwrap_or(""))).collect()
}

#[test]
fn every_command_in_the_readme_parses() {
    let text = readme();
    let segments: Vec<String> = commands(&text).iter().flat_map(|c| tool_segments(c)).map(str::to_string).collect();
    for tool in TOOLS {
        assert!(segments.iter().any(|s| s.starts_with(&format!("{tool} "))), "the README's sh blocks never run {tool}: {segments:#?}");
    }
    let refused: Vec<String> = segments
        .iter()
        .filter_map(|segment| {
            let out = parse_only(segment);
            (!out.status.success()).then(|| format!("{segment}\n  {}", String::from_utf8_lossy(&out.stderr).trim()))
        })
        .collect();
    assert!(refused.is_empty(), "README commands the tools refuse:\n{}", refused.join("\n"));
    // No command escapes the check in an indented code block.
    for line in text.lines().filter(|l| l.starts_with("    ")) {
        let first = line.split_whitespace().next().unwrap_or("");
        assert!(!TOOLS.contains(&first), "a command outside a ```sh block: {line}");
    }
}

/// Stand-ins for the tools, which append their name and arguments (tab-separated, one line
/// a run) to `$NIMBUS_STUB_LOG` and create the files given to `-o` and `--preview`.
fn stubs(dir: &Path) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let script = r#"#!/bin/sh
line=${0##*/}
for a in "$@"; do line="$line	$a"; done
printf '%s\n' "$line" >> "$NIMBUS_STUB_LOG"
prev=
for a in "$@"; do
  case $prev in -o|--preview) [ "$a" = - ] || : > "$a" ;; esac
  prev=$a
done
"#;
    for tool in TOOLS {
        let path = bin.join(tool);
        std::fs::write(&path, script).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    bin
}

/// A run's arguments in an order-free form: each flag with its value (`--albedo 0.95`), each
/// switch (`-v`, `-q`) and each positional argument one unit, the units sorted. (A flag
/// followed by a word not starting with `-` is taken to own it as its value.)
fn units(args: &[&str]) -> Vec<String> {
    let mut units = Vec::new();
    let mut i = 0;
    while i < args.len() {
        let takes_value = args[i].starts_with('-') && !["-v", "-q"].contains(&args[i]) && args.get(i + 1).is_some_and(|next| !next.starts_with('-'));
        units.push(if takes_value { format!("{} {}", args[i], args[i + 1]) } else { args[i].to_string() });
        i += if takes_value { 2 } else { 1 };
    }
    units.sort();
    units
}

/// The runs a stub log holds, each as its tool and [`units`], sorted.
fn runs(log: &Path) -> Vec<(String, Vec<String>)> {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let mut runs: Vec<(String, Vec<String>)> = text
        .lines()
        .map(|l| {
            let fields: Vec<&str> = l.split('\t').collect();
            (fields[0].to_string(), units(&fields[1..]))
        })
        .collect();
    runs.sort();
    runs
}

#[test]
fn the_readme_shows_the_demo_as_scripts_demo_sh_runs_it() {
    let dir = scratch("readme", "demo");
    let bin = stubs(&dir);

    // scripts/demo.sh, run from a copy of the scripts (it works from their parent, writing
    // out/ there) with the stubs as its tools.
    let copy = dir.join("script");
    std::fs::create_dir_all(copy.join("scripts")).unwrap();
    for entry in std::fs::read_dir(root().join("scripts")).unwrap() {
        let entry = entry.unwrap();
        if entry.file_type().unwrap().is_file() {
            std::fs::copy(entry.path(), copy.join("scripts").join(entry.file_name())).unwrap();
        }
    }
    let script_log = dir.join("script.log");
    let out = Command::new("bash").arg(copy.join("scripts/demo.sh")).env("BIN", &bin).env("NIMBUS_STUB_LOG", &script_log).output().unwrap();
    assert!(out.status.success(), "scripts/demo.sh with stand-in tools: {}", String::from_utf8_lossy(&out.stderr));

    // The README's demo: its commands that write into out/, where the demo's results go.
    let readme_dir = dir.join("readme");
    std::fs::create_dir_all(readme_dir.join("out")).unwrap();
    let readme_log = dir.join("readme.log");
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let demo: Vec<String> = commands(&readme()).into_iter().filter(|c| c.contains(" out/")).collect();
    assert!(!demo.is_empty(), "the README shows no demo command (one writing into out/)");
    for command in &demo {
        let out = Command::new("bash").args(["-o", "pipefail", "-c", command]).current_dir(&readme_dir).env("PATH", &path).env("NIMBUS_STUB_LOG", &readme_log).output().unwrap();
        assert!(out.status.success(), "{command}: {}", String::from_utf8_lossy(&out.stderr));
    }

    let (script, shown) = (runs(&script_log), runs(&readme_log));
    assert!(script.len() >= 3, "scripts/demo.sh ran {} tools", script.len());
    let missing = |runs: &[(String, Vec<String>)], from: &[(String, Vec<String>)]| -> Vec<String> { runs.iter().filter(|r| !from.contains(r)).map(|(tool, units)| format!("{tool} {}", units.join(" "))).collect() };
    let (only_script, only_readme) = (missing(&script, &shown), missing(&shown, &script));
    assert!(
        script == shown,
        "the README's demo commands and scripts/demo.sh differ (flags sorted).\nonly in scripts/demo.sh:\n  {}\nonly in the README:\n  {}",
        only_script.join("\n  "),
        only_readme.join("\n  ")
    );
}
