//! The `hypercast` binary: parse, run, map the error to an exit code
//! (`CLI.md`: 0 success, 1 a render failed, 2 bad input). Nothing else.

use clap::Parser;

fn main() {
    // A node thread's panic is caught and reported by the coordinator as
    // one line naming the node; the default hook would add a backtrace
    // note first. Other panics (bugs) keep the default report.
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let node = std::thread::current()
            .name()
            .is_some_and(|n| n.starts_with("hypercast-node-"));
        if !node {
            default(info);
        }
    }));
    let cli = hypercast::cli::Cli::parse();
    if let Err(e) = hypercast::cli::run(cli) {
        eprintln!("hypercast: error: {e}");
        std::process::exit(e.exit_code());
    }
}
