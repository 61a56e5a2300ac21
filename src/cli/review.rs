//! `cmsckf review`: a flight log's summary (see [`cmsckf::review`]) printed
//! as text (or JSON for scripts), with its plots, HTML page and TUM
//! trajectory written where asked.

use std::path::PathBuf;

// The arguments of `cmsckf review` (a plain comment: a doc comment here would
// replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct ReviewArgs {
    input: PathBuf,
    /// Write trajectory.png, error.png, figure1.png, nis.png and timing.png here.
    #[arg(long)]
    plots: Option<PathBuf>,
    /// Export the estimated trajectory in TUM format.
    #[arg(long)]
    tum: Option<PathBuf>,
    /// The keyframe zoomed in Figure 1 (default: the fifth).
    #[arg(long)]
    keyframe: Option<u64>,
    /// Write one self-contained HTML report here (no network needed to view it).
    #[arg(long)]
    html: Option<PathBuf>,
    /// Replace the --html or --tum file if it exists (never the log itself).
    #[arg(long)]
    force: bool,
    #[arg(long)]
    json: bool,
}

/// Refuses an output that is the log being reviewed, or (without `force`)
/// an existing file.
fn check_output(out: &std::path::Path, log: &std::path::Path, force: bool) -> anyhow::Result<()> {
    if cmsckf::io::mcap_log::same_file(out, log) {
        anyhow::bail!(
            "'{}' is the log being reviewed: give another output path",
            out.display()
        );
    }
    if out.exists() && !force {
        anyhow::bail!(
            "'{}' exists: give another output path, or --force to replace it",
            out.display()
        );
    }
    Ok(())
}

/// Runs `cmsckf review` and prints the summary (JSON with `--json`, else
/// aligned text, with a note when the log was cut short).
pub fn review(args: ReviewArgs) -> anyhow::Result<()> {
    let ReviewArgs {
        input,
        plots,
        tum,
        keyframe,
        html,
        force,
        json,
    } = args;
    for out in [&html, &tum].into_iter().flatten() {
        check_output(out, &input, force)?;
    }
    if let Some(dir) = &plots {
        for name in ["trajectory.png", "error.png", "figure1.png", "nis.png", "timing.png"] {
            if cmsckf::io::mcap_log::same_file(&dir.join(name), &input) {
                anyhow::bail!(
                    "--plots {}: would write {name} over the log being reviewed",
                    dir.display()
                );
            }
        }
    }
    // Warnings (a damaged chunk left out, …) reach the user.
    super::init_tracing("warn");
    if let Some(page) = &html {
        cmsckf::review::review_html(&input, page, keyframe)?;
    }
    let s = cmsckf::review::review(&input, plots.as_deref(), tum.as_deref(), keyframe)?;
    if json {
        println!("{}", serde_json::to_string(&s)?);
    } else {
        if s.truncated {
            println!("note: the log ends early (no summary): reviewed up to its last complete chunk");
        }
        print!("{}", s.text());
        if let Some(p) = plots {
            println!("plots in {}", p.display());
        }
        if let Some(p) = html {
            println!("report in {}", p.display());
        }
    }
    Ok(())
}
