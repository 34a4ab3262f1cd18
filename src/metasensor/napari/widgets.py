"""A magicgui form for one ``metasensor`` command, built from the command's own definition.

Every field is one of the command's options (or its input argument): its name, type, default
and tooltip (the option's ``--help`` text, word for word) are read from the CLI's click command,
so the form and the command line cannot drift apart. *Run* starts the command in a worker thread
(napari's ``create_worker``) through :class:`metasensor.napari.jobs.Job`, with a napari progress
bar that has a Cancel button (and a Cancel button in the form); errors become one-line
notifications.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from magicgui import widgets as mw

from metasensor.napari.jobs import CommandRun, Job, JobResult, Progress

__all__ = ["CommandWidget", "cli_params"]


def cli_params(command: str) -> list:
    """The click parameters of ``metasensor <command>``, in the CLI's order."""
    import typer.main

    from metasensor.cli import app

    group = typer.main.get_command(app)
    ctx = group.context_class(group, info_name="metasensor")
    _, cmd, _ = group.resolve_command(ctx, [command])  # a lazy group loads the command here
    return list(cmd.params)


def _kind(param) -> str:
    """"bool", "int", "float", "path" or "str": from typer's annotation of the parameter (typer
    >= 0.2x keeps it in ``type_descriptor``), else from click's parameter type."""
    if getattr(param, "is_flag", False):
        return "bool"
    ann = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    if ann is not None:
        if isinstance(ann, type) and issubclass(ann, Path):
            return "path"
        return {bool: "bool", int: "int", float: "float"}.get(ann, "str")
    name = type(getattr(param, "type", None)).__name__
    return {"BoolParamType": "bool", "IntParamType": "int", "FloatParamType": "float",
            "Path": "path"}.get(name, "str")


class CommandWidget(mw.Container):
    """The form of one command.

    Parameters
    ----------
    viewer : the napari viewer (layers are added to it when a run finishes).
    command : the ``metasensor`` command.
    show : names of the parameters shown, in order (the input argument first; ``out`` is the
        output folder field, always shown).
    choices : fixed choices for text options, by parameter name (first = default when the
        CLI's default is None: shown as "(default)" and not passed).
    out_name : the file in the output folder that ``--out`` names (None: ``--out`` is the
        folder).
    on_done : ``callback(widget, result)`` when a run finished (adds its layers).
    folders : parameters that name a folder (a Zarr store, an output folder).
    """

    def __init__(self, viewer, command: str, show: Sequence[str], *, choices=None,
                 out_name: str | None = None, on_done: Callable | None = None,
                 folders: Sequence[str] = ("out",)) -> None:
        super().__init__(labels=True)
        self.viewer = viewer
        self.command = command
        self.out_name = out_name
        self.on_done = on_done
        self.job: Job | None = None
        self.worker = None
        self.outcome: JobResult | None = None
        self.pbar = None
        params = {p.name: p for p in cli_params(command)}
        self.params = [params[n] for n in show]
        self.fields: dict[str, mw.Widget] = {}
        for p in self.params:
            w = self._field(p, (choices or {}).get(p.name), p.name in folders)
            self.fields[p.name] = w
            self.append(w)
        self.run_button = mw.PushButton(text=f"Run {command}")
        self.cancel_button = mw.PushButton(text="Cancel", enabled=False)
        self.status = mw.Label(value="")
        self.status.native.setWordWrap(True)  # long messages wrap instead of widening the dock
        self.run_button.changed.connect(self.start)
        self.cancel_button.changed.connect(self.cancel)
        self.extend([mw.Container(widgets=[self.run_button, self.cancel_button],
                                  layout="horizontal", labels=False), self.status])

    # ------------------------------------------------------------------ fields
    @staticmethod
    def _field(p, choices, folder: bool) -> mw.Widget:
        kind = _kind(p)
        tip = (p.help or "").strip()
        label = p.name.replace("_", " ")
        default = p.default if not callable(p.default) else None
        if choices:
            opts = list(choices) if default is not None else ["(default)", *choices]
            value = default if default in opts else opts[0]
            return mw.ComboBox(name=p.name, label=label, choices=opts, value=value, tooltip=tip)
        if kind == "bool":
            return mw.CheckBox(name=p.name, label=label, value=bool(default), tooltip=tip)
        if kind == "path":
            mode = "d" if folder else "r"
            return mw.FileEdit(name=p.name, label=label, mode=mode, tooltip=tip,
                               value=str(default) if default is not None else "")
        if kind == "int" and default is not None:
            return mw.SpinBox(name=p.name, label=label, value=int(default), min=-1,
                              max=1_000_000, tooltip=tip)
        if kind == "float" and default is not None:
            return mw.FloatSpinBox(name=p.name, label=label, value=float(default), min=0.0,
                                   max=1e9, step=0.1, tooltip=tip)
        # text, or a number with no default (empty: not given, the command's default applies)
        return mw.LineEdit(name=p.name, label=label, tooltip=tip,
                           value="" if default is None else str(default))

    def values(self) -> dict:
        """The form's values, by parameter name."""
        return {name: w.value for name, w in self.fields.items()}

    def set(self, **values) -> CommandWidget:
        """Set fields by parameter name (for scripts and tests); returns the widget."""
        for name, value in values.items():
            self.fields[name].value = value
        return self

    def command_run(self) -> CommandRun:
        """The :class:`CommandRun` the form describes (one line ``ValueError`` if incomplete)."""
        inputs, options, settings = [], [], {}
        out = None
        for p in self.params:
            value = self.fields[p.name].value
            settings[p.name] = str(value) if isinstance(value, Path) else value
            empty = value is None or value == "" or value == "(default)" or (
                isinstance(value, Path) and str(value) in ("", "."))
            if p.name == "out":
                if empty:
                    raise ValueError("choose an output folder (out)")
                out = Path(value).expanduser().resolve()
                continue
            if p.param_type_name == "argument":
                if empty:
                    raise ValueError(f"choose the input ({p.name})")
                inputs.append(str(Path(value).expanduser().resolve()))
                continue
            flag = p.opts[0]
            if _kind(p) == "bool":
                if value:
                    options.append((flag, None))
                elif p.secondary_opts:
                    options.append((p.secondary_opts[0], None))
                continue
            if empty:
                continue
            if isinstance(value, Path):
                value = str(value.expanduser().resolve())
            if getattr(p, "multiple", False):  # repeated option: "a; b" -> --x a --x b
                options += [(flag, v.strip()) for v in str(value).split(";") if v.strip()]
                continue
            options.append((flag, value))
        return CommandRun(self.command, tuple(inputs), tuple(options), out, self.out_name,
                          settings)

    # ------------------------------------------------------------------ running
    @property
    def running(self) -> bool:
        return self.worker is not None

    def start(self, *_) -> None:
        """Run the command in a worker thread (a second click while running is ignored)."""
        from napari.qt.threading import create_worker
        from napari.utils.notifications import show_error

        if self.running:
            return
        try:
            run = self.command_run()
        except ValueError as exc:
            show_error(str(exc))
            self.status.value = f"not run: {exc}"
            return
        self.outcome = None
        self.job = Job(run)
        self.pbar = _progress_bar(self.command, self.job.cancel)
        self.worker = create_worker(_guarded, self.job)
        self.worker.yielded.connect(self._progress)
        self.worker.returned.connect(self._finished)
        self.run_button.enabled, self.cancel_button.enabled = False, True
        self.status.value = f"running {self.command} ..."
        self.worker.start()

    def cancel(self, *_) -> None:
        """End the running command; its partial outputs are removed."""
        if self.job is not None:
            self.job.cancel()
            self.status.value = "cancelling ..."

    def _progress(self, report: Progress | None) -> None:
        if report is None or self.pbar is None:
            return
        if report.total and self.pbar.total != report.total:
            self.pbar.total = report.total
        if report.desc:
            self.pbar.set_description(f"{self.command}: {report.desc}")
        if report.n >= self.pbar.n:
            self.pbar.update(report.n - self.pbar.n)

    def _finished(self, result: JobResult) -> None:
        from napari.utils.notifications import show_error, show_info

        self.outcome = result
        if self.pbar is not None:
            self.pbar.close()
            self.pbar = None
        self.worker = None
        self.run_button.enabled, self.cancel_button.enabled = True, False
        if result.status == "failed":
            show_error(f"{self.command}: {result.error}")
            self.status.value = f"failed: {result.error}"
            return
        if result.status == "cancelled":
            show_info(f"{self.command} cancelled; nothing was written")
            self.status.value = "cancelled (nothing written)"
            return
        self.status.value = (result.stdout.strip().splitlines() or ["done"])[-1][:200]
        if self.on_done is not None:
            try:
                self.on_done(self, result)
            except Exception as exc:  # noqa: BLE001 - a notification, not a traceback dialog
                line = str(exc).strip().splitlines()[0] if str(exc).strip() else repr(exc)
                show_error(f"{self.command}: cannot show the result: {line}")


def _guarded(job: Job):
    """``job.steps()``, with any unexpected failure turned into a failed result (one line)."""
    try:
        return (yield from job.steps())
    except Exception as exc:  # noqa: BLE001 - reported as a one-line notification
        return JobResult("failed", job.run.out, error=str(exc).splitlines()[0] if str(exc)
                         else type(exc).__name__)


def _progress_bar(desc: str, on_cancel: Callable):
    """A napari progress bar whose Cancel button (activity dock) ends the run."""
    from napari.utils import cancelable_progress

    class _JobProgress(cancelable_progress):
        def cancel(self) -> None:
            super().cancel()
            on_cancel()

    return _JobProgress(total=0, desc=desc)
