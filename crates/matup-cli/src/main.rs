//! The `matup` binary, with matup's built-in plugins.

fn main() -> std::process::ExitCode {
    matup_cli::main()
}
