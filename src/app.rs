//! Command-line arguments, stage two: set up the process (threads) and dispatch each command
//! to [`crate::commands`], the service or the benches. Errors carry context for people
//! (anyhow); the libraries below return enums.

use anyhow::{Context, Result};

use crate::cli::{Cli, Command};

pub fn run(cli: Cli) -> Result<()> {
    if let Some(threads) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global()
            .context("setting up the thread pool")?;
    }
    match cli.command {
        None => crate::commands::run_default(&cli.default_output, cli.quiet, cli.max_memory),
        Some(Command::Render(args)) => crate::commands::render(&args, cli.quiet, cli.max_memory),
        Some(Command::Solve(args)) => crate::commands::solve(&args, cli.quiet, cli.max_memory),
        Some(Command::Info(args)) => crate::commands::info(&args),
        Some(Command::Export(args)) => crate::commands::export(&args),
        Some(Command::Serve(args)) => crate::service::run_cli(&args, cli.quiet, cli.max_memory),
        Some(Command::Bench(crate::cli::BenchCommand::Albedo(args))) => {
            crate::bench_albedo::run(&args, cli.quiet, cli.max_memory)
        }
        Some(Command::Validate(args)) => crate::commands::validate(&args, cli.quiet),
        Some(Command::Compare(args)) => crate::commands::compare(&args),
    }
}
