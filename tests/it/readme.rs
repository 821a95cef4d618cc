//! Every `volrad` command the README and the user docs show parses with the program's own
//! argument parser: a flag renamed in the code but not in the docs (or the other way round)
//! fails here, not in front of a new user.

use std::fs;

use crate::fixtures::root;
use clap::Parser;
use volrad::cli::Cli;

/// Splits a shell line into words: whitespace separates, single and double quotes group, a
/// `#` outside quotes starts a comment, `\` at the end of a line continues it (joined before).
fn shell_words(line: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut word = String::new();
    let mut quote: Option<char> = None;
    let mut in_word = false;
    for c in line.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                in_word = true;
            }
            (None, '#') if !in_word => break,
            (None, c) if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            (None, c) => {
                word.push(c);
                in_word = true;
            }
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

/// The `volrad …` commands in the fenced `sh` blocks of a Markdown file (also `cargo run
/// --release -- …` and `target/release/volrad …`), with continuation lines joined.
fn volrad_commands(markdown: &str) -> Vec<Vec<String>> {
    let mut commands = Vec::new();
    let mut in_block = false;
    let mut pending = String::new();
    for line in markdown.lines() {
        let trimmed = line.trim();
        if trimmed.starts_with("```") {
            in_block = !in_block && (trimmed == "```sh" || trimmed == "```bash");
            continue;
        }
        if !in_block {
            continue;
        }
        pending.push_str(trimmed.trim_end_matches('\\'));
        pending.push(' ');
        if trimmed.ends_with('\\') {
            continue;
        }
        let text = std::mem::take(&mut pending);
        for part in text.split("&&") {
            let words = shell_words(part);
            let args: Vec<String> = match words.iter().map(String::as_str).collect::<Vec<_>>()[..] {
                ["volrad", ..] | ["target/release/volrad", ..] => words[1..].to_vec(),
                ["cargo", "run", "--release", "--", ..] => words[4..].to_vec(),
                _ => continue,
            };
            // A trailing `&` (run in the background) is the shell's, not volrad's.
            let args = args.into_iter().filter(|a| a != "&").collect();
            commands.push(args);
        }
    }
    // Whole commands in running text and tables (`volrad solve s.toml -o s.volrad`): those
    // with an output; mentions of a command or flag (`volrad solve --json`) and synopses with
    // [optional] parts are not commands to run.
    for (i, span) in markdown.split('`').enumerate() {
        let whole = span.contains(" -o ") && !span.contains('[');
        if i % 2 == 1 && !span.contains('\n') && whole {
            for part in span.split("&&") {
                let words = shell_words(part);
                let args: Vec<String> = match words.iter().map(String::as_str).collect::<Vec<_>>()[..]
                {
                    ["volrad", _, ..] => words[1..].to_vec(),
                    ["target/release/volrad", _, ..] => words[1..].to_vec(),
                    _ => continue,
                };
                commands.push(args);
            }
        }
    }
    commands
}

#[test]
fn every_command_in_the_docs_parses() {
    let mut checked = 0;
    let mut failures = Vec::new();
    for doc in [
        "README.md",
        "docs/albedo.md",
        "docs/validation.md",
        "docs/performance.md",
    ] {
        let text = fs::read_to_string(root().join(doc)).unwrap();
        for args in volrad_commands(&text) {
            checked += 1;
            let argv = std::iter::once("volrad".to_string()).chain(args.iter().cloned());
            if let Err(e) = Cli::try_parse_from(argv) {
                failures.push(format!("{doc}: volrad {}: {}", args.join(" "), e.kind()));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
    assert!(checked >= 12, "only {checked} commands found");
}

#[test]
fn the_extraction_sees_quotes_comments_and_continuations() {
    assert_eq!(
        shell_words(r#"volrad render "a b.toml" -o x.png  # comment"#),
        ["volrad", "render", "a b.toml", "-o", "x.png"]
    );
    let md = "```sh\nvolrad bench albedo s.toml \\\n  --iteration jacobi -o b\nls\n```\n";
    assert_eq!(
        volrad_commands(md),
        [[
            "bench",
            "albedo",
            "s.toml",
            "--iteration",
            "jacobi",
            "-o",
            "b"
        ]]
    );
    // A flag the program does not have is refused by the parser the test uses.
    assert!(
        Cli::try_parse_from(["volrad", "render", "--method", "path-trace", "-o", "x.png"]).is_err()
    );
}

/// The README's guide, run as written and in order in a fresh directory holding a copy of
/// `data/`: every command exits 0 and writes what the guide says it writes — the new user's
/// first hour, without a command that fails after the work. Left out here, by name: the
/// path-traced reference, the albedo bench and validation (minutes each) and the server (a
/// process that does not end): `tests/readme_guide.py`, which CI runs with the release binary,
/// runs the whole guide block and the service's curl examples as written.
#[test]
fn the_readme_guide_runs_as_written() {
    let readme = fs::read_to_string(root().join("README.md")).unwrap();
    // The guide is the `sh` block that opens with the bare `volrad`.
    let blocks: Vec<&str> = readme
        .split("```sh\n")
        .skip(1)
        .map(|b| b.split("```").next().unwrap())
        .collect();
    let guide = blocks
        .iter()
        .find(|b| b.lines().any(|l| shell_words(l) == ["volrad"]))
        .expect("the README has a guide block opening with `volrad`");
    let dir = tempfile::tempdir().unwrap();
    fs::create_dir(dir.path().join("data")).unwrap();
    for entry in fs::read_dir(root().join("data")).unwrap() {
        let path = entry.unwrap().path();
        fs::copy(
            &path,
            dir.path().join("data").join(path.file_name().unwrap()),
        )
        .unwrap();
    }
    let (mut ran, mut left_out) = (Vec::new(), Vec::new());
    for line in guide.lines() {
        let words = shell_words(line);
        if words.first().map(String::as_str) != Some("volrad") {
            continue;
        }
        let costly = ["--path-trace", "bench", "validate", "serve"];
        if words.iter().any(|w| costly.contains(&w.as_str())) {
            left_out.push(words.join(" "));
            continue;
        }
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_volrad"))
            .args(&words[1..])
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "`{}` failed: {}",
            words.join(" "),
            String::from_utf8_lossy(&out.stderr)
        );
        ran.push(words.join(" "));
    }
    assert!(ran.len() >= 8, "ran {ran:#?}");
    assert_eq!(left_out.len(), 4, "left out {left_out:#?}");
    // What the guide's comments promise.
    for file in [
        "volrad-default.png",
        "cloud.volrad",
        "front.png",
        "orbit/front_000.png",
        "orbit/front_035.png",
        "close.exr",
        "fluence.nrrd",
    ] {
        let path = dir.path().join(file);
        assert!(
            path.is_file() && fs::metadata(&path).unwrap().len() > 0,
            "{file} missing after {ran:#?}"
        );
    }
    let out_dir: Vec<_> = fs::read_dir(dir.path().join("out")).unwrap().collect();
    assert!(!out_dir.is_empty(), "out/ is empty");
}
