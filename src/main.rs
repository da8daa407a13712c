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

/// Output piped into `head` and closed early ends the process quietly, as with other Unix tools,
/// instead of a panic in `println!` (Rust ignores SIGPIPE by default). Every socket of ours is
/// UDP and serial ports report a closed peer otherwise, so nothing else gets the signal.
#[cfg(unix)]
fn default_sigpipe() {
    // SAFETY: sets the default disposition of one signal, before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() -> std::process::ExitCode {
    #[cfg(unix)]
    default_sigpipe();
    let cli = vidslam::cli::Cli::parse();
    match vidslam::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}
