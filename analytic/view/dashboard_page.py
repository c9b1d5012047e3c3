"""The dashboard's page (analytic.view.dashboard): the farm's line and plots, the runs compared,
one run inspected and a panel per run (analytic.view.dashboard_panels), built for each page Bokeh's
server opens and brought up to date once a REFRESH_SECONDS; the server, and its loop until Ctrl-C.

Bokeh is the `dashboard` extra: this module imports it at its top, and is itself imported only
when the dashboard is served (analytic.view.dashboard.serve).
"""

import html
from collections.abc import Callable
from pathlib import Path

from bokeh.application import Application
from bokeh.application.handlers.function import FunctionHandler
from bokeh.document import Document
from bokeh.layouts import column, row
from bokeh.models import ColumnDataSource, Div
from bokeh.plotting import figure
from bokeh.server.server import Server
from tornado.ioloop import IOLoop, PeriodicCallback

from gainfarm.analytic.tuning.run import RECORD_SECONDS
from gainfarm.analytic.view.dashboard import REFRESH_SECONDS, Watch
from gainfarm.analytic.view.dashboard_panels import WIDE, Compare, Inspector, RunPanel
from gainfarm.cli import interrupts


def page(watch: Watch) -> Callable[[Document], None]:
    """The function Bokeh calls to build each new page's document."""

    def build(document: Document) -> None:
        farm_line = Div(name="farm", text="", styles={"font-size": "110%"})
        farm_series = ColumnDataSource(
            {"t": [], "jobs_per_s": [], "queued": [], "busy": []}, name="farm-series"
        )
        since = "seconds since the dashboard started"
        throughput = figure(
            title="throughput (jobs/s over the last minute)",
            x_axis_label=since,
            height=220,
            **WIDE,
        )
        throughput.line("t", "jobs_per_s", source=farm_series, line_width=2)
        queue = figure(title="queued jobs and busy workers", x_axis_label=since, height=220, **WIDE)
        queue.line("t", "queued", source=farm_series, line_width=2, legend_label="queued")
        queue.line(
            "t", "busy", source=farm_series, line_width=2, color="orange", legend_label="busy"
        )
        queue.legend.location = "top_left"
        compare, inspector = Compare(), Inspector()
        roots = ", ".join(map(str, watch.roots))
        heading = Div(
            text=f"<h2>runs</h2>under {html.escape(roots)}: running ones first, then the "
            f"newest, each as its records say (a run writes them every {RECORD_SECONDS:g} s "
            "and as it stops, so a running one's may be that far behind its terminal)"
        )
        runs = column(heading, **WIDE)
        panels: dict[Path, RunPanel] = {}
        farm_shown = [-1]  # the farm's version on the page

        def update() -> None:
            version, text, series = watch.farm_now()
            if version != farm_shown[0]:
                farm_line.text = html.escape(text)
                farm_series.data = series
                farm_shown[0] = version
            found = watch.runs()
            for directory, run_version, view in found:
                if directory not in panels:
                    panels[directory] = RunPanel(directory)
                panels[directory].show(run_version, view)
            order = [heading, *(panels[directory].layout for directory, _, _ in found)]
            if list(runs.children) != order:  # a new run, or one that stopped: reordered
                runs.children = order
            compare.show(found)
            inspector.show(found)

        document.title = "gainfarm dashboard"
        farm = [Div(text="<h2>gainfarm</h2>"), farm_line, row(throughput, queue, **WIDE)]
        compared = [Div(text="<h2>compare</h2>"), compare.layout]
        inspected = [Div(text="<h2>inspect</h2>"), inspector.layout]
        document.add_root(column(*farm, *compared, *inspected, runs, **WIDE))
        update()
        document.add_periodic_callback(update, int(REFRESH_SECONDS * 1000))

    return build


def serve(watch: Watch, port: int, address: str = "127.0.0.1") -> Server:
    """Bokeh's server for the page on `address`:`port`, started in this thread's event loop (run
    it with `run_forever`, stop it with its `stop`). OSError if the port cannot be had."""
    server = Server(
        {"/": Application(FunctionHandler(page(watch)))},
        port=port,
        address=address,
        allow_websocket_origin=[f"{address}:{port}", f"localhost:{port}"],
        num_procs=1,
    )
    server.start()
    return server


def run_forever() -> None:
    """Serve until Ctrl-C: Tornado's loop, woken every so often so that a Ctrl-C is seen."""
    loop = IOLoop.current()

    def check() -> None:
        if interrupts.INTERRUPTED.is_set():
            loop.stop()

    PeriodicCallback(check, 200).start()
    loop.start()
    interrupts.check()
