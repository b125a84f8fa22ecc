//! The `hypercast` binary: parse, run, map the error to an exit code
//! (`CLI.md`: 0 success, 1 a render failed, 2 bad input). Nothing else.

use clap::Parser;

fn main() {
    let cli = hypercast::cli::Cli::parse();
    if let Err(e) = hypercast::cli::run(cli) {
        eprintln!("hypercast: error: {e}");
        std::process::exit(e.exit_code());
    }
}
