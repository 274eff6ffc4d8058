//! `matup-blinn-phong`: matup's whole command line, with the `blinn-phong` shading model
//! linked in next to the built-in plugins.

use matup_blinn_phong as _;

fn main() -> std::process::ExitCode {
    matup_cli::main()
}
