use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = vidslam::cli::Cli::parse();
    match vidslam::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
