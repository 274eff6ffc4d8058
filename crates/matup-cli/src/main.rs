//! The `matup` command: a thin layer over the matup libraries. It parses arguments, calls
//! the library, and turns errors into messages and exit codes.

mod list;
mod material_args;
mod render;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

// Link every built-in plugin so the registries see them.
use matup_shading as _;
use matup_upsamplers as _;

#[derive(Parser)]
#[command(
    name = "matup",
    version,
    about = "Upsample physically based materials (SVBRDF maps)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List every registered upsampler and shading model with its options.
    List,
    /// Render a material under one light or a contact sheet of the training lights.
    Render(render::RenderArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::List => list::run(),
        Command::Render(args) => render::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
