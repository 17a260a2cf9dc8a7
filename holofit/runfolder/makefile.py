"""The text of a run folder's Makefile, and of the Makefile that runs many run folders.

The run folder's Makefile has one target per stage output, with the stage's real inputs as
prerequisites (crop <- movie, backgrounds, instrument; prefit <- crops; library <- prefit,
particle; fit <- library, particle; analyze <- fit table), so make reruns exactly what a
changed input invalidates. Two rules make it safe to interrupt and to rerun:

- **Completion.** Each stage writes its table only when every frame is done (the batch runner,
  :mod:`holofit.batch.runner`; crop writes ``crops.csv`` last), so the table's existence is
  the completion signal. ``.PRECIOUS`` keeps make from deleting a table when interrupted, and
  ``.DELETE_ON_ERROR`` is left unset.
- **Resume or overwrite.** A stage's earlier results (its table, its journal) newer than every
  prerequisite come from an interrupted run of the same inputs: the stage runs without
  ``--overwrite`` and resumes from the journal. Earlier results older than a prerequisite were
  made from other inputs or settings, which the stages refuse to mix: the stage runs with
  ``--overwrite``. Make knows the first case by the target's absence, the second by its age;
  a journal left by a killed run is judged by its own age, since the target is then missing.

Stage settings (extra options, engine, analysis model, temperature, input paths) are written
by make itself, at parse time, to ``settings/<stage>``, rewritten only when they change; the
stage's target depends on that file, so a settings change (also on make's command line)
reruns the stage. How the stages run (``JOBS``, ``SCHEDULER``, ``BATCH_OPTS``, ``HOLOFIT``)
is not recorded and reruns nothing.
"""

from __future__ import annotations

from holofit.runfolder.spec import RunFolderConfig, make_value

__all__ = ["BATCH_MAKEFILE_MARK", "render_batch_makefile", "render_run_makefile", "targets"]

#: first line of the Makefile that runs every run folder beside it
BATCH_MAKEFILE_MARK = "# holofit: runs every run folder in this folder"


def targets(spec: RunFolderConfig) -> dict[str, str]:
    """Stage -> the file that marks it complete (the library only for anisotropic particles)."""
    out = {"crop": "crop/crops.csv", "prefit": "prefit/prefit.csv"}
    if spec.anisotropic:
        out["library"] = "library/library.csv"
    out |= {"fit-initial": "fit/static.json", "fit": "fit/fit.csv",
            "analyze": "analysis/summary.csv"}
    return out


def _header(spec: RunFolderConfig) -> str:
    lines = [f"# {line}" for line in spec.header]
    return "\n".join(lines)


_GUIDE = """\
#
#   make                       run every stage that is out of date (the first time: all)
#   make fit                   stop after a stage: crop prefit library fit-initial fit analyze
#   make JOBS=8                8 worker processes per stage (default: every CPU; 0: none,
#                              frames run in the stage's own process)
#   make SCHEDULER=tcp://10.0.0.5:8786   frames on a Dask cluster (or a scheduler file)
#   make -n                    show what would run; make -q: exit status 0 if nothing would
#   make clean                 remove every stage's output (not the movie, not the configs)
# (from elsewhere: make -C THIS_FOLDER ...). Stages run one after another, each using JOBS
# workers; make -j adds nothing inside one folder (many folders: holofit's docs, run folders).
#
# Targets, and what makes them out of date (a newer prerequisite reruns the stage and every
# stage after it):
#   crop/crops.csv        movie, background(s), dark frame(s), instrument.toml, settings/crop
#   prefit/prefit.csv     crop/crops.csv, settings/prefit
{library_line}#   fit/static.json       {fit_inputs}, particle.toml, settings/fit
#                         (initial pass: every parameter free on some frames)
#   fit/fit.csv           fit/static.json and the same (final pass: static parameters fixed)
#   analysis/summary.csv  fit/fit.csv, settings/analyze
# Editing particle.toml reruns {particle_reruns}, not crop and prefit.
# Editing instrument.toml reruns everything. settings/STAGE holds the stage's settings below:
# make writes it as it reads this file, and rewrites it only when they change (also when they
# are given on the command line: make CROP_OPTS=...).
#
# Interrupted runs. A stage writes its table only when every frame is done, so the table's
# existence means "done"; meanwhile each finished frame goes to a journal (TABLE.journal).
# When make runs a stage, earlier results of it (table or journal) that are newer than all its
# prerequisites come from an interrupted run with the same inputs: the stage resumes from the
# journal and fits only the missing frames. Earlier results older than a prerequisite were
# made from other inputs or settings: the stage runs with --overwrite, which discards them.
# (The stages refuse to mix results of different settings, and a resume must keep finished
# frames: make's timestamps tell the two apart.) make OVERWRITE=1 discards the earlier results
# of every stage that runs (needed only when an input changed while its stage was running:
# the stage then says that its earlier results have other settings).
# .PRECIOUS keeps make from deleting a table when interrupted; .DELETE_ON_ERROR is not set, so
# a stage that failed after its table was complete (in its plots) keeps it.
"""


_VARIABLES = """\
# ---- inputs: referred to, not copied (movies are big); absolute paths ----------------------
MOVIE      = {movie}
BACKGROUND = {backgrounds}
DARK       = {darks}
DARK_COUNT = {dark_count}
# yes: the movie is background-divided already (no BACKGROUND, no DARK)
NORMALIZED = {normalized}

# ---- stage settings: a change reruns the stage and every stage after it --------------------
# scattering engine of library and fit: auto, exact, mie, builtin, adda (empty: the particle
# config's, i.e. auto: the exact one where the particle has one)
ENGINE        = {engine}
# diffusion analysis (rod, janus, sphere; empty: each track's from the particle model the fit
# gave it) and sample temperature (C)
MODEL         = {model}
TEMPERATURE_C = {temperature}
# extra options of each stage (holofit STAGE --help)
CROP_OPTS     = {crop}
PREFIT_OPTS   = {prefit}
LIBRARY_OPTS  = {library}
FIT_OPTS      = {fit}
ANALYZE_OPTS  = {analyze}

# ---- how the stages run: changing these reruns nothing -------------------------------------
# the holofit command (the one that wrote this folder)
HOLOFIT    ?= {holofit}
# worker processes of every stage (empty: every CPU; 0: in the stage's own process)
JOBS       =
# Dask scheduler: address (tcp://host:8786) or scheduler file
SCHEDULER  =
# more options of prefit, library and fit that change how, not what (--dask-local, --progress)
BATCH_OPTS =
# 1: discard earlier results of every stage that runs (see above)
OVERWRITE  =
"""


_MACHINERY = """\
# ---------------------------------------------------------------------------------------------
.SUFFIXES:
.PHONY: all crop prefit library fit-initial fit analyze settings clean
.PRECIOUS: {targets}

all: analyze
crop: crop/crops.csv
prefit: prefit/prefit.csv
{library_alias}
fit-initial: fit/static.json
fit: fit/fit.csv
analyze: analysis/summary.csv
# record the settings (settings/STAGE), run nothing
settings: ;

LIGHT = $(if $(NORMALIZED),--normalized) $(addprefix -b ,$(BACKGROUND)) \\
  $(addprefix --dark ,$(DARK)) $(if $(DARK_COUNT),--dark-count $(DARK_COUNT))
ENGINE_OPT = $(if $(ENGINE),--engine $(ENGINE))
BATCH = $(if $(JOBS),-j $(JOBS)) $(if $(SCHEDULER),--scheduler $(SCHEDULER)) $(BATCH_OPTS)

# $(call record,STAGE,VARIABLE): settings/STAGE holds the value of VARIABLE, rewritten (so newer
# than the stage's table) only when it changes; run as the Makefile is read, except by a dry
# run (make -n), which changes nothing
# (it names the records that would change, so that it shows the stages they rerun)
DRY_RUN = $(findstring n,$(firstword -$(MAKEFLAGS)))
changed = t='$(subst ','\\'',$(strip $($(2))))' && [ "$$(cat settings/$(1) 2>/dev/null)" != "$$t" ]
record = $(if $(DRY_RUN),$(eval CHANGED_SETTINGS += $(shell $(changed) && echo settings/$(1))),\\
  $(shell mkdir -p settings && $(changed) && printf '%s\\n' "$$t" > settings/$(1)))
CROP_SETTINGS    = movie $(MOVIE) background $(BACKGROUND) dark $(DARK) dark-count $(DARK_COUNT) \\
  normalized $(NORMALIZED) options $(CROP_OPTS)
PREFIT_SETTINGS  = options $(PREFIT_OPTS)
LIBRARY_SETTINGS = engine $(ENGINE) options $(LIBRARY_OPTS)
FIT_SETTINGS     = engine $(ENGINE) options $(FIT_OPTS)
ANALYZE_SETTINGS = model $(MODEL) temperature-c $(TEMPERATURE_C) options $(ANALYZE_OPTS)
$(call record,crop,CROP_SETTINGS)
$(call record,prefit,PREFIT_SETTINGS)
$(call record,library,LIBRARY_SETTINGS)
$(call record,fit,FIT_SETTINGS)
$(call record,analyze,ANALYZE_SETTINGS)
# a dry run: the records that would change count as changed; a record not written yet too
.PHONY: $(CHANGED_SETTINGS)
settings/%: ;

# $(call overwrite,FILES): --overwrite when one of FILES (the stage's earlier results: table,
# journal) exists and a prerequisite is newer than it; nothing otherwise (a resume, or a
# first run)
overwrite = $(if $(OVERWRITE),--overwrite,$(shell for f in $(1); do [ -e "$$f" ] || continue; \\
  for p in $^; do if [ "$$p" -nt "$$f" ]; then echo --overwrite; exit 0; fi; done; done))

crop/crops.csv: $(MOVIE) $(BACKGROUND) $(DARK) instrument.toml settings/crop
\t$(HOLOFIT) crop $(MOVIE) $(strip $(LIGHT)) -i instrument.toml -o crop $(strip $(CROP_OPTS) \\
\t  $(if $(JOBS),-j $(JOBS)))

prefit/prefit.csv: crop/crops.csv settings/prefit
\t$(HOLOFIT) prefit crop -o prefit $(strip $(PREFIT_OPTS) $(BATCH) $(call overwrite,$@ $@.journal))
{library_rule}
FIT = $(HOLOFIT) fit crop --prefit prefit {library_option}-p particle.toml {population}-o fit

fit/static.json: {fit_prerequisites} particle.toml {population_files}settings/fit
\t$(FIT) --pass initial $(strip $(ENGINE_OPT) $(FIT_OPTS) $(BATCH) \\
\t  $(call overwrite,$@ fit/initial.csv fit/initial.csv.journal \\
\t    $(wildcard fit/initial*_frames.csv)))

fit/fit.csv: fit/static.json {fit_prerequisites} particle.toml {population_files}settings/fit
\t$(FIT) --pass final $(strip $(ENGINE_OPT) $(FIT_OPTS) $(BATCH) \\
\t  $(call overwrite,$@ $@.journal fit/fit_chunks.csv fit/fit_frames.csv))

analysis/summary.csv: fit/fit.csv settings/analyze
\t$(HOLOFIT) analyze fit/fit.csv -o analysis $(strip $(if $(MODEL),--model $(MODEL)) \\
\t  --temperature-c $(TEMPERATURE_C) $(ANALYZE_OPTS))

clean:
\trm -rf crop prefit library fit analysis settings
"""

_LIBRARY_RULE = """
library/library.csv: crop/crops.csv prefit/prefit.csv particle.toml settings/library
\t$(HOLOFIT) library crop --prefit prefit -p particle.toml -o library \\
\t  $(strip $(ENGINE_OPT) $(LIBRARY_OPTS) $(BATCH) $(call overwrite,$@ $@.journal))
"""

_NO_LIBRARY = """\
library:
\t@echo "library: skipped: a {kind} has no orientation to search (the fit starts from the prefit)"
"""


def render_run_makefile(spec: RunFolderConfig) -> str:
    """The Makefile of a run folder (see the module docstring)."""
    done = targets(spec)
    if spec.anisotropic:
        library_line = ("#   library/library.csv   prefit/prefit.csv, particle.toml, "
                        "settings/library\n")
        fit_inputs = "library/library.csv"
        particle_reruns = "library, fit and analyze"
        library_alias = "library: library/library.csv"
        library_rule = _LIBRARY_RULE
        library_option = "--library library "
        fit_prerequisites = "crop/crops.csv prefit/prefit.csv library/library.csv"
    else:
        library_line = (f"#   (no library: a {spec.particle_kind} has no orientation; written "
                        "for this particle model:\n#   after changing it to an anisotropic "
                        "one, run holofit init again with --force)\n")
        fit_inputs = "prefit/prefit.csv"
        particle_reruns = "fit and analyze"
        library_alias = _NO_LIBRARY.format(kind=spec.particle_kind)
        library_rule = ""
        library_option = ""
        fit_prerequisites = "crop/crops.csv prefit/prefit.csv"
    guide = _GUIDE.format(library_line=library_line, fit_inputs=fit_inputs,
                          particle_reruns=particle_reruns)
    dark_count = "" if spec.dark_count is None else f"{spec.dark_count:g}"
    variables = _VARIABLES.format(
        movie=spec.movie, backgrounds=" ".join(spec.backgrounds), darks=" ".join(spec.darks),
        dark_count=dark_count, normalized="yes" if spec.normalized else "",
        # each track is analysed with its own model (the fit table's), unless one is forced
        engine=spec.engine or "", model=spec.analysis_model if spec.analysis_forced else "",
        temperature=f"{spec.temperature_c:g}",
        **{stage: make_value(spec.option(stage)) for stage in
           ("crop", "prefit", "library", "fit", "analyze")},
        holofit=make_value(spec.holofit),
    )
    machinery = _MACHINERY.format(
        targets=" ".join(done.values()), library_alias=library_alias.rstrip("\n"),
        library_rule=library_rule, library_option=library_option,
        fit_prerequisites=fit_prerequisites,
        population="".join(f"-p {a} " for a in spec.alternatives),
        population_files="".join(f"{a} " for a in spec.alternatives),
    )
    text = "\n".join([_header(spec), guide, variables, machinery])
    return "".join(line.rstrip() + "\n" for line in text.splitlines())


def render_batch_makefile() -> str:
    """A Makefile that runs every run folder beside it (each subfolder with a Makefile)."""
    return f"""\
{BATCH_MAKEFILE_MARK} (written by `holofit init --batch-makefile`).
#
#   make -j4 JOBS=2 -k    four run folders at a time, two workers each; -k: a failing movie
#                         does not stop the others
#   make TARGET=prefit    every run folder up to a stage (crop prefit library fit analyze)
#   make run01            one of them
# Variables given here (JOBS, SCHEDULER, OVERWRITE, ...) reach every run folder.
RUNS := $(patsubst %/Makefile,%,$(wildcard */Makefile))
TARGET ?= all

.PHONY: all $(RUNS)
all: $(RUNS)
$(RUNS):
\t$(MAKE) -C $@ $(TARGET)
"""
