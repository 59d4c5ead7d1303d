//! The `nis` command. (Minimal front end for the path tracer; merged with the flow commands.)

mod render;

use clap::{Parser, Subcommand};

/// Neural importance sampling from the command line.
#[derive(Parser)]
#[command(name = "nis", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Commands,
}

#[derive(Subcommand)]
enum Commands {
    /// Render a scene with the CPU path tracer.
    Render(render::RenderArgs),
    /// Compare an image with a reference (MAPE, relMSE, error map).
    Compare(render::CompareArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match &cli.command {
        Commands::Render(a) => render::run_render(a),
        Commands::Compare(a) => render::run_compare(a),
    };
    if let Err(e) = result {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}
