"""``evpose refine SCENE [--object NAME] [--offset] [--json] [--apply]``: object poses (and the clock
offset) from event/edge alignment (DESIGN section 5: per object ``dR_deg``, ``dt_mm``,
``score_before``, ``score_after``, ``runtime_s``). ``--apply`` stores the accepted results as one undo step
and saves (:func:`evpose.core.align.apply.save_applied`).

``--joint [--hand-eye] [--no-clock]``: clock, object poses (and a hand-eye correction) fitted together
(:func:`evpose.core.align.joint_fit.refine_joint`); the document is the :class:`~evpose.core.align.joint_result.
JointResult`: clock at the top (``offset_us``, ``skew_ppm``, their standard errors), ``objects`` (per object
``dT_base``, ``dt_mm``, ``dR_deg`` and standard errors), ``held`` (objects kept for lack of evidence) and
``hand_eye``; ``--apply`` stores all of it as one undo step."""
from __future__ import annotations

from evpose.app.cli.errors import CliError, command
from evpose.app.cli.estimates import check_windows, edges_line
from evpose.app.cli.json_output import emit
from evpose.app.cli.progress import Progress

__all__ = ["cmd_refine", "object_line"]


def object_names(scene, args) -> list[str]:
    """The objects to refine: ``--object`` (refused with one line when the scene has none of that name) or all."""
    names = [args.object] if args.object else scene.object_names
    for n in names:
        if n not in scene.object_names:
            raise CliError(f"{scene.manifest.path}: objects: no object named {n!r} "
                           f"(have {', '.join(scene.object_names) or 'none'})")
    return names


def object_line(name: str, r) -> str:
    """One line for the pose refinement ``r`` of object ``name``."""
    sb = "n/a" if r.score_before is None else f"{r.score_before:.3f}"
    sa = "n/a" if r.score_after is None else f"{r.score_after:.3f}"
    return (f"{name}: {'accepted' if r.accepted else 'kept start'}: dR {r.dR_deg:.3f} deg, dt "
            f"{r.dt_mm:.2f} mm; score {sb} -> {sa}; {r.n_windows} windows, {r.iterations} "
            f"iterations, {r.runtime_s:.1f} s" + (f" ({r.reason})" if r.reason else ""))


def _refine(scene, args, out: dict, lines: list[str]) -> bool:
    """Refine the offset (with ``--offset``) then each object's pose; fills ``out`` and ``lines``.
    Returns whether ``--apply`` changed the document (one undo step)."""
    from evpose.core.align.apply import apply_offset_result
    from evpose.core.align.clock_refine import refine_offset
    from evpose.core.align.pose_refine import refine_object
    from evpose.core.align.refine_result import RefineParams
    from evpose.core.document.estimates import apply_pose_estimate
    from evpose.core.document.history import History

    names = object_names(scene, args)
    params = RefineParams(n_windows=args.windows)
    history = History(scene.corrections)
    changed = False
    clock = None
    with history.group("refine from events"):
        if args.offset:
            with Progress("refine offset", not args.quiet) as progress:
                r = refine_offset(scene, params=params, progress=progress)
            out["offset"] = r.to_json()
            lines.append(edges_line(r, "offset from edges")
                         + f"; objective {r.objective_before:.4f} -> {r.objective_after:.4f}")
            if r.accepted:
                clock = scene.clock_with(offset_us=int(r.offset_us), skew_ppm=r.skew_ppm)  # poses fit on it
            if args.apply:
                changed |= apply_offset_result(history, scene, r)
        for n in names:
            with Progress(f"refine {n}", not args.quiet) as progress:
                r = refine_object(scene, n, params=params, clock=clock, progress=progress)
            out["objects"][n] = r.to_json()
            lines.append(object_line(n, r))
            if args.apply and r.accepted:
                apply_pose_estimate(history, n, r.dT_base, f"refine {n}")
                changed = True
    return changed


def _refine_joint(scene, args, out: dict, lines: list[str]) -> bool:
    """``--joint``: one fit of clock, poses (and hand-eye) (:func:`~evpose.core.align.refine_run.run_refine_joint`);
    fills ``out`` and ``lines``; applies as one undo step with ``--apply`` and saves."""
    from evpose.app.cli.estimates import change_lines, joint_lines
    from evpose.core.align.refine_run import JointRunOptions, run_refine_joint

    names = object_names(scene, args) if args.object else None
    opts = JointRunOptions(clock=not args.no_clock, objects=None if names is None else tuple(names),
                           hand_eye=args.hand_eye, windows=args.windows or JointRunOptions.windows, apply=args.apply)
    with Progress("refine jointly", not args.quiet) as progress:
        run = run_refine_joint(scene, opts, progress=progress)
    out.update(run.data)
    lines.extend(joint_lines(run.result, "joint fit"))
    lines.extend(change_lines(run.data, args.apply))
    if run.saved_line:
        lines.append(run.saved_line)
    return False            # saved already


@command("refine")
def cmd_refine(args) -> int:
    if args.windows is None:
        args.windows = 24 if args.joint else 12
    check_windows(args)
    if (args.hand_eye or args.no_clock) and not args.joint:
        raise CliError("--hand-eye and --no-clock go with --joint")
    if args.joint and args.offset:
        raise CliError("--offset and --joint: --joint fits the clock already (--no-clock keeps it)")
    from evpose.core.data.scene import Scene

    scene = Scene.open(args.scene)
    if not scene.has_poses:
        scene.close()
        scene.require_poses("pose refinement")
    out: dict = {"objects": {}}
    lines: list[str] = []
    try:
        changed = (_refine_joint if args.joint else _refine)(scene, args, out, lines)
        out["applied"] = bool(out.get("applied")) or bool(args.apply and changed)
        if changed and args.apply:
            from evpose.core.align.apply import save_applied

            lines.append(save_applied(scene, out))
    finally:
        scene.close()
    emit(args, out, "\n".join(lines))
    return 0
