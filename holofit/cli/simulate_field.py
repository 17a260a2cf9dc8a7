"""``holofit simulate field-of-view``: a movie of several particles described in a scene file."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.cli.common import out_dir_option


@click.command("field-of-view")
@click.argument("scene_file", metavar="SCENE", type=click.Path(exists=True, dir_okay=False,
                                                                path_type=Path))
@out_dir_option()
def simulate_field_cmd(scene_file: Path, out: Path) -> None:
    """A movie of every particle of SCENE (a TOML file: the instrument, the frames and one
    [[particle]] table per particle with its config, start and motion; see
    holofit.simulate.scene). The holograms are superposed as fields.

    Writes OUT/movie.tif, OUT/background.tif and OUT/truth.csv (+ sidecars): one truth row per
    (particle, frame).
    """
    from holofit.progress import progress_bar
    from holofit.simulate.field_of_view import simulate_field_of_view
    from holofit.simulate.scene import load_scene

    scene = load_scene(scene_file)
    with progress_bar(scene.n_frames, "simulate", unit="frame") as bar:
        result = simulate_field_of_view(
            scene.particles, scene.instrument, scene.frame_shape, noise=scene.noise,
            seed=scene.seed, out_dir=out, progress=bar.update)
    click.echo(f"wrote {result.movie} ({scene.n_frames} frame(s), {len(scene.particles)} "
               f"particle(s)), {result.background}, {result.truth_table}")
