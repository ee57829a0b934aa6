//! The book's command reference, printed from the clap definitions themselves (`ecsync
//! help-markdown`, hidden): a flag added, renamed or given another default changes the page,
//! and `scripts/regen-docs.py --check` fails until the book is regenerated, so the reference
//! cannot drift from the binary the way a hand-written one does.

use clap::CommandFactory;
use std::process::ExitCode;

/// Prints the Markdown reference of every visible command of `C`. The title is the book's
/// chapter heading; clap-markdown's footer (a line about the generator, with a link) is left
/// out so the chapter holds nothing but the commands.
pub fn print<C: CommandFactory>() -> ExitCode {
    let options = clap_markdown::MarkdownOptions::new()
        .title("Command reference".to_string())
        .show_footer(false);
    print!("{}", clap_markdown::help_markdown_custom::<C>(&options));
    ExitCode::SUCCESS
}

#[cfg(test)]
mod tests {
    #[derive(Debug, clap::Parser)]
    #[command(name = "tool")]
    struct Tool {
        #[command(subcommand)]
        command: Sub,
    }

    #[derive(Debug, clap::Subcommand)]
    enum Sub {
        /// Does the visible thing.
        Shown {
            /// How many.
            #[arg(long, default_value_t = 3)]
            count: u32,
        },
        #[command(hide = true)]
        Hidden,
    }

    #[test]
    fn the_reference_has_the_flags_and_not_the_hidden_commands() {
        let options = clap_markdown::MarkdownOptions::new().show_footer(false);
        let md = clap_markdown::help_markdown_custom::<Tool>(&options);
        assert!(md.contains("## `tool shown`"), "{md}");
        assert!(md.contains("--count"), "{md}");
        assert!(md.contains("Default value: `3`"), "{md}");
        assert!(!md.contains("hidden"), "{md}");
    }
}
