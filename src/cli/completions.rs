//! `cmsckf completions SHELL`: shell completion scripts, generated from the
//! command line's own definition so they never fall behind it.

use clap::CommandFactory;

// The arguments of `cmsckf completions` (a plain comment: a doc comment here
// would replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct CompletionsArgs {
    /// bash, zsh, fish, elvish or powershell.
    shell: clap_complete::Shell,
}

/// Prints the completion script for `shell` on stdout, e.g.
/// `cmsckf completions bash > /etc/bash_completion.d/cmsckf`.
pub fn completions<C: CommandFactory>(args: &CompletionsArgs) {
    let mut cmd = C::command();
    clap_complete::generate(args.shell, &mut cmd, "cmsckf", &mut std::io::stdout());
}
