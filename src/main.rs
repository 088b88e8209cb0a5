fn main() {
    std::process::exit(diffcassi::cli::main());
}
