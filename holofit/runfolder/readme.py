"""The README.md of a run folder: what is in it, and what each make target does."""

from __future__ import annotations

from holofit.runfolder.spec import RunFolderConfig

__all__ = ["render_readme"]


def _inputs(spec: RunFolderConfig) -> list[str]:
    lines = [f"- movie: `{spec.movie}`"]
    if spec.normalized:
        lines.append("- the movie is background-divided already (`--normalized`)")
    lines += [f"- background: `{b}`" for b in spec.backgrounds]
    lines += [f"- dark frame: `{d}`" for d in spec.darks]
    if spec.dark_count is not None:
        lines.append(f"- dark level: {spec.dark_count:g} counts")
    lines += [f"- `instrument.toml`: copy of `{spec.instrument_source}`",
              f"- `particle.toml`: copy of `{spec.particle_source}` (a {spec.particle_kind})"]
    return lines


def render_readme(spec: RunFolderConfig) -> str:
    """The run folder's README (Markdown)."""
    rows = [
        "| `make crop` | `crop/crops.csv`, `crop/crops.tif` | normalise every frame by the "
        "background, find every hologram, link them into tracks (`particle`), crop each |",
        "| `make prefit` | `prefit/prefit.csv` | Lorenz-Mie fit of every crop: x, y, z, "
        "radius, index, alpha |",
    ]
    if spec.anisotropic:
        rows.append("| `make library` | `library/library.csv` | best starting orientations of "
                    "every frame (DDA holograms over a grid of orientations) |")
    rows += [
        "| `make fit-initial` | `fit/initial.csv`, `fit/static.json` | DDA fit of the first "
        "frames with every parameter free; the static parameters' robust average |",
        "| `make fit` | `fit/fit.csv` | DDA fit of every frame, static parameters fixed |",
        f"| `make` (`make analyze`) | `analysis/summary.csv` | diffusion analysis "
        f"({_analysis_model(spec)}, {spec.temperature_c:g} C) against theory |",
    ]
    library_note = ("" if spec.anisotropic else
                    f"\nA {spec.particle_kind} has no orientation: there is no library stage "
                    "(`make library` says so); the fit starts from the prefit.\n")
    reruns = ("library, fit and analyze" if spec.anisotropic else "fit and analyze")
    return "\n".join([
        "# holofit run folder",
        "",
        "One movie through every stage of holofit, driven by make. Written by `holofit init`;",
        "the `Makefile` says the same in its comments, with every setting.",
        "",
        *_inputs(spec),
        "",
        "The movie and backgrounds are referred to by absolute path, not copied (movies are "
        "big). The two configs are copies: edit them here.",
        "",
        "## Running",
        "",
        "In this folder (from elsewhere: `make -C FOLDER ...`):",
        "",
        "```",
        "make                        # every stage that is out of date",
        "make JOBS=8                 # 8 worker processes per stage",
        "make SCHEDULER=tcp://10.0.0.5:8786           # frames on a Dask cluster",
        "make FIT_OPTS='--initial-frames 100'         # a stage setting (reruns fit, analyze)",
        "```",
        "",
        "| target | writes | what it does |",
        "| --- | --- | --- |",
        *rows,
        library_note,
        "Several particles in view: every table is keyed by (particle, frame), `fit/` holds "
        "each track's fit in `particle_N/` and every track's rows in `fit.csv`, and "
        "`analysis/` each track's summary, `tracks.csv` and the tracks pooled "
        "(`pooled.csv`); no option is needed.",
        "",
        "A second `make` does nothing. Editing `particle.toml` reruns " + reruns + ", not "
        "crop and prefit; editing `instrument.toml`, or the movie, reruns everything; a "
        "stage setting (`CROP_OPTS`, `ENGINE`, `MODEL`, ...; in the Makefile or on make's "
        "command line) reruns that stage and every stage after it.",
        "",
        "Interrupted (Ctrl-C, a kill, a preempted job)? Run `make` again: the interrupted "
        "stage resumes from its journal and fits only the frames that are missing. A stage "
        "whose inputs or settings changed since its earlier results discards them "
        "(`--overwrite`, decided by make); `make OVERWRITE=1` discards them for every stage "
        "that runs.",
        "",
        "`make clean` removes every stage's output (`crop/ prefit/ library/ fit/ analysis/ "
        "settings/`).",
        "",
    ])


def _analysis_model(spec: RunFolderConfig) -> str:
    """The analysis model the Makefile gives (unless forced: each track's own)."""
    if spec.analysis_forced:
        return f"`--model {spec.analysis_model}`"
    if spec.alternatives:
        return "each track with the model of the particle the fit gave it"
    return (f"each track with the model of the particle the fit gave it "
            f"({spec.analysis_model})")
