use clap::Parser;

/// The error and its causes on one line; a cause already spelled out by the message above it
/// (our error types print their source inline) is not repeated.
fn error_line(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.contains(&c) {
            msg.push_str(": ");
            msg.push_str(&c);
        }
    }
    msg
}

fn main() -> std::process::ExitCode {
    let cli = vidslam::cli::Cli::parse();
    match vidslam::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}
