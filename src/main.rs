//! The `cac` command line: one small file per subcommand under `cli/`; each parses its
//! arguments, calls the library and prints. The compute device is chosen here, at the edge.

mod cli;

use clap::Parser;

fn main() {
    let args = cli::Cli::parse();
    if let Err(e) = cli::run(args) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
