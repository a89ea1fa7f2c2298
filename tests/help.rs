//! `--help` of every tool (issue #31): every flag has a description, defaults are shown one
//! way (clap's `[default: ...]`), the flags are grouped under headings, and the examples the
//! help gives are accepted by the tools' parsers (run with `NIMBUS_PARSE_ONLY`, which exits
//! once the flags parsed).

use std::process::Command;

mod common;

use common::{bin, parse_only, TOOLS};

fn help(tool: &str) -> String {
    let out = Command::new(bin(tool)).arg("--help").output().unwrap();
    assert!(out.status.success(), "{tool} --help: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

/// Each argument of a help text (its header line, trimmed) and its description: the text after
/// the header on its line (short help), else the more deeply indented lines under it.
fn arguments(text: &str) -> Vec<(String, String)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut args = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        // clap indents a header 2 spaces (6 for a long flag without a short one) and its
        // description 10 in the long help.
        let indent = line.len() - line.trim_start().len();
        let is_header = (2..=6).contains(&indent) && matches!(line.trim_start().chars().next(), Some('-' | '[' | '<'));
        if !is_header {
            continue;
        }
        let trimmed = line.trim();
        let (header, mut description) = match trimmed.split_once("  ") {
            Some((h, d)) => (h.to_string(), d.trim().to_string()),
            None => (trimmed.to_string(), String::new()),
        };
        for next in &lines[i + 1..] {
            if next.starts_with("        ") {
                description.push(' ');
                description.push_str(next.trim());
            } else {
                break;
            }
        }
        args.push((header, description.trim().to_string()));
    }
    args
}

#[test]
fn every_flag_has_a_description_and_one_default() {
    let mut missing = Vec::new();
    for tool in TOOLS {
        let text = help(tool);
        let args = arguments(&text);
        assert!(args.len() > 5, "{tool}: no arguments found in its help:\n{text}");
        for (header, description) in &args {
            if description.is_empty() {
                missing.push(format!("{tool} {header}"));
            }
            assert!(description.matches("[default:").count() <= 1, "{tool} {header}: a default shown twice: {description}");
            assert!(!description.contains("(default"), "{tool} {header}: a default in another form than [default: ...]: {description}");
        }
        for heading in ["Input:", "Output:", "Quality:"] {
            assert!(text.lines().any(|l| l == heading), "{tool}: no '{heading}' heading:\n{text}");
        }
    }
    assert!(missing.is_empty(), "flags without a description: {missing:?}");
}

#[test]
fn the_shared_flags_are_one_definition_in_nimbus_render() {
    let render = help("nimbus-render");
    let cache = help("vdbcache");
    let description = |text: &str, flag: &str| {
        arguments(text).into_iter().find(|(h, _)| h.starts_with(&format!("--{flag} ")) || h == &format!("--{flag}")).map(|a| a.1)
    };
    for flag in ["albedo", "extinction", "g", "sun", "point", "sky", "environment", "eye", "look-at", "view-dir", "width", "height"] {
        let (Some(r), Some(c)) = (description(&render, flag), description(&cache, flag)) else { panic!("--{flag} missing in nimbus-render or vdbcache") };
        assert_eq!(r, c, "--{flag}: nimbus-render's description differs from vdbcache's");
    }
    // Typed: nimbus-render checks the value itself, as vdbcache does.
    let out = Command::new(bin("nimbus-render")).args(["in.ply", "-o", "out.exr", "--albedo", "grey"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--albedo"));
}

/// The example commands under the help's `Example:`/`Examples:` heading, one a line.
fn examples(text: &str) -> Vec<String> {
    let mut lines = text.lines().skip_while(|l| !l.starts_with("Example")).skip(1);
    let mut commands = Vec::new();
    for line in lines.by_ref() {
        if !line.starts_with("  ") {
            break;
        }
        commands.push(line.trim().to_string());
    }
    commands
}

#[test]
fn the_examples_in_the_help_parse() {
    for tool in TOOLS {
        let commands = examples(&help(tool));
        assert!(!commands.is_empty(), "{tool}: no example in its help");
        assert!(commands.iter().any(|c| c.contains(tool)), "{tool}: its examples do not run it: {commands:?}");
        for command in commands {
            for segment in command.split(" | ") {
                let program = segment.split_whitespace().next().unwrap();
                assert!(TOOLS.contains(&program), "{tool}: the example runs '{program}', not a nimbus tool: {command}");
                let out = parse_only(segment);
                assert!(out.status.success(), "{tool}: the example '{segment}' is refused: {}", String::from_utf8_lossy(&out.stderr));
            }
        }
    }
    // The hook does not pass what the parser refuses.
    let out = Command::new(bin("vdbcache")).args(["--no-such-flag"]).env("NIMBUS_PARSE_ONLY", "1").output().unwrap();
    assert_eq!(out.status.code(), Some(2));
}
