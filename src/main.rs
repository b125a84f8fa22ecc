//! The `hypercast` binary: parse, run, map the error to an exit code
//! (`CLI.md`: 0 success, 1 a render failed, 2 bad input). Nothing else.

use std::io::IsTerminal;

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
    // Ctrl-C, SIGTERM or SIGHUP would end the process without the
    // destructors that remove an image's temporary file; the handler
    // removes any still being written, then exits as interrupted (130, as
    // a shell reports SIGINT). Where it cannot be installed the signals
    // keep their default action, which writes nothing either.
    let _ = ctrlc::set_handler(|| {
        hypercast::report::image_io::discard_unfinished();
        // On a terminal the progress bar's line is cleared first.
        let clear = if std::io::stderr().is_terminal() {
            "\r\x1b[2K"
        } else {
            ""
        };
        eprintln!("{clear}hypercast: interrupted; no file left half-written");
        std::process::exit(130);
    });
    let cli = hypercast::cli::Cli::parse();
    if let Err(e) = hypercast::cli::run(cli) {
        eprintln!("hypercast: error: {e}");
        std::process::exit(e.exit_code());
    }
}
