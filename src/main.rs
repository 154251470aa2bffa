use clap::Parser;

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = gilab::cli::Cli::parse();
    if let Err(e) = gilab::cli::run(cli) {
        // One line, no backtrace: user errors are not crashes.
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
