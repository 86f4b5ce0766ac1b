//! The `vemlight` command: parse the arguments, run the command (`vemlight::cli`), map the
//! result to an exit code.

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = vemlight::cli::Cli::parse();
    match vemlight::cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            // A reader that closed the pipe early (`| head`) is a normal end.
            if err
                .downcast_ref::<std::io::Error>()
                .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
            {
                return ExitCode::SUCCESS;
            }
            eprintln!("vemlight: error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
