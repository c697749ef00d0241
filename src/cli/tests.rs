//! The command line as a whole: one help text per shared flag, one name per concept, each
//! error cause printed once.

use super::Cli;
use clap::CommandFactory;
use std::collections::BTreeMap;

/// `(command, long flag, help text)` of every flag of every command.
fn flags() -> Vec<(String, String, String)> {
    let cli = Cli::command();
    let mut out = Vec::new();
    for sub in cli.get_subcommands() {
        for arg in sub.get_arguments() {
            if let Some(long) = arg.get_long() {
                let help = arg.get_help().map(|h| h.to_string()).unwrap_or_default();
                out.push((sub.get_name().to_string(), long.to_string(), help));
            }
        }
    }
    out
}

#[test]
fn a_flag_shared_by_several_commands_has_one_help_text() {
    let mut by_flag: BTreeMap<String, BTreeMap<String, Vec<String>>> = BTreeMap::new();
    for (cmd, long, help) in flags() {
        by_flag
            .entry(long)
            .or_default()
            .entry(help)
            .or_default()
            .push(cmd);
    }
    let differing: Vec<String> = by_flag
        .iter()
        .filter(|(_, helps)| helps.len() > 1)
        .map(|(flag, helps)| format!("--{flag}: {helps:#?}"))
        .collect();
    assert!(differing.is_empty(), "{}", differing.join("\n"));
}

#[test]
fn one_name_per_concept() {
    // Spellings replaced by one name (still accepted as hidden aliases): none may come back
    // as a flag's name; lengths carry their unit; one spelling of "regularize".
    let replaced = [
        ("stereo-method", "method"),
        ("max-depth", "max-depth-m"),
        ("voxel-size", "voxel-size-m"),
        ("truncation", "truncation-m"),
    ];
    let all = flags();
    for (old, new) in replaced {
        assert!(
            all.iter().all(|(_, long, _)| long != old),
            "--{old} is back: it is --{new}"
        );
    }
    for (cmd, long, help) in &all {
        assert!(
            !long.contains("regularis") && !help.contains("regularis"),
            "{cmd} --{long}: one spelling, regularize"
        );
    }
}

#[test]
fn an_error_prints_each_cause_once() {
    // An error whose message includes its source's (as `path: source` errors do), under a
    // context: the source is not printed again below it.
    let io = std::io::Error::other("no such frame in the sequence");
    let e = anyhow::Error::new(denser::Error::io("d/image_1/000001.png", io))
        .context("reconstructing d");
    assert_eq!(
        super::error_lines(&e),
        [
            "error: reconstructing d",
            "  caused by: d/image_1/000001.png: no such frame in the sequence",
        ]
    );
    // Distinct causes all stay.
    let e = anyhow::anyhow!("disk full")
        .context("writing m")
        .context("committing");
    assert_eq!(
        super::error_lines(&e),
        [
            "error: committing",
            "  caused by: writing m",
            "  caused by: disk full"
        ]
    );
}
