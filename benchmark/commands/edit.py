"""``trase-bench edit remove|extract|recolor|compose``: edit a run, a fitted capture or an
edited scene; the result is a folder that render, view and edit open again."""

from __future__ import annotations

import click

from benchmark.commands.text_options import text_options, text_request

_FOLDER = click.Path(exists=True, file_okay=False)


def _selection_options(f):
    f = click.option("--selected", is_flag=True, help="The clusters the run's prompts chose.")(f)
    f = click.option("--click", "clicks", multiple=True, metavar="VIEW:X,Y",
                     help="Select the cluster under a pixel of a view (repeatable).")(f)
    f = click.option("--mask", "masks", multiple=True, metavar="VIEW:PATH",
                     help="Select the clusters a 2D mask image of a view covers (repeatable).")(f)
    f = click.option("--clusters", default=None, metavar="IDS", help="Cluster ids, e.g. 3,7.")(f)
    f = click.option("--cache", type=click.Path(file_okay=False), default=None,
                     help="Stage cache of a run (default: the .cache above it).")(f)
    f = click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
                     help="Folder for the edited scene.")(f)
    f = click.option("--run", "run_dir", required=True, type=_FOLDER,
                     help="A run, a trase-bench fit folder or an edited scene.")(f)
    return text_options(f)


def _open(run_dir, cache, clusters, clicks, selected, masks, **text):
    from benchmark.errors import UserError
    from benchmark.scene.folders import open_scene_folder, resolve_selection

    folder = open_scene_folder(run_dir, cache)
    found: list = []
    ks, sel = resolve_selection(folder, clusters, clicks, selected, masks=masks, text=text_request(**text), found=found)
    for choice in found:
        click.echo(f"text {choice.line()}")
    if sel is None:
        raise UserError("say what to edit: --clusters IDS, --click VIEW:X,Y, --mask VIEW:PATH, --text PHRASE or "
                        "--selected")
    if not sel.any():
        raise UserError(f"the selection (clusters {ks}) holds no gaussians")
    # what the edit record keeps of the selection: its clusters, and each phrase's choice
    return folder, {"clusters": ks, **({"text": [c.to_dict() for c in found]} if found else {})}, sel


def _done(path, record_note: str) -> None:
    import json

    rec = json.loads(path.read_text())
    n = rec["n_gaussians"]
    click.echo(f"{rec['operation']}: {n['before']} -> {n['after']} gaussians ({record_note}); "
               f"{path.parent}  preview {path.parent / rec['preview']}")
    click.echo(f"next: trase-bench render --run {path.parent}   |   trase-bench view --run {path.parent}")


@click.group(name="edit")
def edit() -> None:
    """Edit a scene: remove, extract or recolour a selection, or compose objects of two scenes."""


@edit.command(name="remove")
@_selection_options
def remove_cmd(run_dir, out_dir, cache, clusters, clicks, selected, masks, **text) -> None:
    """Delete the selected gaussians."""
    from benchmark.scene.edit import write_edit
    from trase.edit import remove

    folder, chosen, sel = _open(run_dir, cache, clusters, clicks, selected, masks, **text)
    ks = chosen["clusters"]
    _done(write_edit(folder, remove(folder.model, sel), out_dir, "remove", chosen), f"clusters {ks}")


@edit.command(name="extract")
@_selection_options
@click.option("--ply", "ply_path", default=None, type=click.Path(dir_okay=False),
              help="Also write the object as one 3DGS PLY (what 3DGS viewers open).")
@click.option("--time", "at_time", default=None, type=click.FloatRange(0.0, 1.0),
              help="With --ply: the object as it stands at this time (0..1), its motion applied; default canonical.")
def extract_cmd(run_dir, out_dir, cache, clusters, clicks, selected, masks, ply_path, at_time, **text) -> None:
    """Keep only the selected gaussians (and, with --ply, write them as one PLY)."""
    from benchmark.scene.edit import write_edit
    from trase.edit import export_object_ply, extract

    folder, chosen, sel = _open(run_dir, cache, clusters, clicks, selected, masks, **text)
    ks = chosen["clusters"]
    _done(write_edit(folder, extract(folder.model, sel), out_dir, "extract", chosen), f"clusters {ks}")
    if ply_path:
        export_object_ply(folder.model, sel, ply_path, time=at_time)
        click.echo(f"object PLY ({int(sel.sum())} gaussians, {'canonical' if at_time is None else f'at time {at_time}'})"
                   f": {ply_path}")


@edit.command(name="recolor")
@_selection_options
@click.option("--rgb", default=None, metavar="R,G,B", help="Set the colour (0..1 each).")
@click.option("--shift", default=None, metavar="R,G,B", help="Add to the colour (-1..1 each).")
def recolor_cmd(run_dir, out_dir, cache, clusters, clicks, selected, masks, rgb, shift, **text) -> None:
    """Set or shift the colour of the selected gaussians."""
    from benchmark.errors import UserError
    from benchmark.scene.edit import parse_vector, write_edit
    from trase.edit import recolor

    if (rgb is None) == (shift is None):
        raise UserError("recolor: give exactly one of --rgb R,G,B or --shift R,G,B")
    folder, chosen, sel = _open(run_dir, cache, clusters, clicks, selected, masks, **text)
    ks = chosen["clusters"]
    value = {"rgb": parse_vector(rgb, "--rgb"), "shift": parse_vector(shift, "--shift")}
    edited = recolor(folder.model, sel, **value)
    _done(write_edit(folder, edited, out_dir, "recolor", {**chosen, **value}), f"clusters {ks}")


@edit.command(name="compose")
@_selection_options
@click.option("--from", "from_dir", required=True, type=_FOLDER, help="The scene to take the object from.")
@click.option("--from-clusters", default=None, metavar="IDS", help="Its clusters to insert.")
@click.option("--from-click", "from_clicks", multiple=True, metavar="VIEW:X,Y", help="Its object under a click.")
@click.option("--from-selected", is_flag=True, help="The clusters its run's prompts chose.")
@click.option("--translate", default="0,0,0", metavar="X,Y,Z", help="Move the object (scene units).")
@click.option("--rotate", default="0,0,0", metavar="RX,RY,RZ", help="Turn it (degrees about x, y, z).")
@click.option("--time-offset", default=0.0, type=float, help="The object shows its time t + offset.")
def compose_cmd(run_dir, out_dir, cache, clusters, clicks, selected, masks, from_dir, from_clusters, from_clicks,
                from_selected, translate, rotate, time_offset, **text) -> None:
    """Insert an object of another scene (or of this one) with a rigid transform and a time
    offset; each part keeps its own motion. --clusters/--click/--mask/--selected pick nothing here:
    the base scene is kept whole (use them to remove first, with edit remove)."""
    from benchmark.errors import UserError
    from benchmark.scene.edit import parse_vector, write_edit
    from benchmark.scene.folders import open_scene_folder, resolve_selection
    from trase.edit import RigidTransform, compose, extract

    if clusters or clicks or selected or masks or text["texts"]:
        raise UserError("compose: select the object with --from-clusters/--from-click/--from-selected")
    base = open_scene_folder(run_dir, cache)
    other = open_scene_folder(from_dir, cache)
    ks, sel = resolve_selection(other, from_clusters, from_clicks, from_selected)
    if sel is None or not sel.any():
        raise UserError("compose: say which object to insert (--from-clusters, --from-click or --from-selected)")
    tf = RigidTransform.from_euler(parse_vector(rotate, "--rotate"), parse_vector(translate, "--translate"))
    edited = compose(base.model, extract(other.model, sel), tf, time_offset)
    params = {"from": str(other.path.resolve()), "from_clusters": ks, "translate": translate, "rotate": rotate,
              "time_offset": time_offset}
    _done(write_edit(base, edited, out_dir, "compose", params), f"inserted clusters {ks} of {other.path}")


@edit.command(name="style")
@_selection_options
@click.option("--style", "style_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The style image.")
@click.option("--vgg", "vgg_path", default=None, type=click.Path(dir_okay=False),
              help="VGG-16 weights (torchvision's vgg16-397923af.pth or a state dict with features.N keys).")
@click.option("--iterations", default=200, type=int, show_default=True)
@click.option("--lr", default=0.02, type=float, show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bar.")
def style_cmd(run_dir, out_dir, cache, clusters, clicks, selected, masks, style_path, vgg_path, iterations, lr,
              quiet, **text) -> None:
    """Restyle the selection's colours after a style image (NNFM on VGG-16 features)."""
    from rich.progress import Progress

    from benchmark.scene.edit import write_edit
    from imagefiles import read_rgb
    from trase.edit.style import StyleConfig, VGG16Features, stylize

    vgg = VGG16Features.load(vgg_path)  # before anything else: the usual missing piece
    folder, chosen, sel = _open(run_dir, cache, clusters, clicks, selected, masks, **text)
    ks = chosen["clusters"]
    cfg = StyleConfig(iterations=iterations, lr=lr)
    with Progress(disable=quiet, transient=True) as bar:
        task = bar.add_task("style", total=iterations)
        edited, losses = stylize(folder.model, sel, [c for _, c in folder.views], read_rgb(style_path), vgg, cfg,
                                 progress=lambda it, loss: bar.update(task, advance=1, description=f"style {loss:.3f}"))
    params = {**chosen, "style": str(style_path), "iterations": iterations, "lr": lr,
              "content_weight": cfg.content_weight, "loss_first": losses[0], "loss_last": losses[-1]}
    _done(write_edit(folder, edited, out_dir, "style", params), f"clusters {ks}, loss {losses[0]:.3f} -> {losses[-1]:.3f}")
