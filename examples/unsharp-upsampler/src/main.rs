//! `matup-unsharp`: matup's whole command line, with the `unsharp` upsampler linked in next
//! to the built-in plugins.

use matup_unsharp as _;

fn main() -> std::process::ExitCode {
    matup_cli::main()
}
