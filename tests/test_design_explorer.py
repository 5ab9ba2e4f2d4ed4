"""The interactive Pareto explorer (eval.design.explorer): its data, and the page in a real headless browser."""

import shutil
import time
import urllib.parse
from pathlib import Path

import pytest

from delta_env.geometry import NOMINAL_GEOMETRY, DeltaGeometry
from delta_env.scenario import load_geometry
from eval.design import explorer, performance, profiles, report
from eval.design.report import performance_row
from tests.figure_checks import hidden_legend_entries, kept_figures

BROWSER_PROGRAMS = ("chromium", "chromedriver")
"""Debian's chromium and chromium-driver packages (scripts/setup.sh installs them), looked up on PATH."""

FRONT_GEOMETRIES = (
    DeltaGeometry(ra=0.16, rb=0.05, l1=0.32, l2=0.95),
    DeltaGeometry(ra=0.22, rb=0.05, l1=0.36, l2=0.95),
    DeltaGeometry(ra=0.20, rb=0.05, l1=0.40, l2=1.045),
)


@pytest.fixture(scope="module")
def study() -> tuple[list[performance.Performance], dict[str, performance.Performance]]:
    """A small front and its named designs: the second front design is the "compromise"."""
    front = [performance.evaluate(g) for g in FRONT_GEOMETRIES]
    assert all(p.feasible for p in front), [p.reason for p in front]
    return front, {"nominal": performance.evaluate(NOMINAL_GEOMETRY), "compromise": front[1]}


@pytest.fixture(scope="module")
def page(study, tmp_path_factory) -> Path:
    front, named = study
    return explorer.write_explorer(front, named, tmp_path_factory.mktemp("explorer") / "explorer.html")


def test_named_designs_come_first_and_front_duplicates_are_merged(study):
    front, named = study
    designs = explorer.explorer_designs(front, named, cycle=0)
    assert [d["name"] for d in designs] == ["nominal", "compromise", "front design 0", "front design 2"]
    assert [d["kind"] for d in designs] == ["nominal", "named", "front", "front"]
    assert designs[1]["row"] == performance_row(front[1])  # every column of the CSV row, new ones included
    assert designs[0]["file"] == "design-nominal.toml"


def test_every_designs_geometry_file_reads_back(study, tmp_path):
    front, named = study
    for design, performance_ in zip(
        explorer.explorer_designs(front, named, cycle=0), [*named.values(), front[0], front[2]], strict=True
    ):
        path = tmp_path / design["file"]
        path.write_text(design["toml"])
        assert load_geometry(path) == performance_.geometry  # the file --geometry reads


def test_profiles_in_the_page_are_the_designs_own(study):
    front, named = study
    cycle = profiles.worst_cycle(named["nominal"])
    design = explorer.explorer_designs(front, named, cycle)[2]
    profile = profiles.design_profile(front[0], cycle)
    stride = explorer.PROFILE_STRIDE
    assert design["profile"]["time"] == pytest.approx(profile.trajectory.time[::stride].tolist(), abs=1e-5)
    assert design["profile"]["torque"][1] == pytest.approx(profile.torque[::stride, 1].tolist(), abs=0.006)


def test_column_labels_carry_their_units():
    assert explorer.column_label("peak_torque_nm") == "peak torque (N m)"
    assert explorer.column_label("workspace_m3") == "workspace (m³)"
    assert explorer.column_label("picks_per_min_light") == "picks/min, light payload"
    assert explorer.column_label("picks_per_min") == "picks/min"
    assert explorer.column_label("speed_m_s") == "speed (m/s)"
    assert explorer.column_label("drive_max_speed_rad_s") == "drive max speed (rad/s)"
    assert explorer.column_label("cylinder_top_m") == "cylinder top (m)"
    assert explorer.column_label("ra") == "ra (m)"
    row = performance_row(performance.evaluate(NOMINAL_GEOMETRY))
    labels = [explorer.column_label(column) for column in row]
    assert len(set(labels)) == len(labels)
    assert not [label for label in labels if "_" in label or " (s)" in label]  # words, units written as units


def test_pareto_figure_shows_its_legend_and_its_whole_title(study, tmp_path, monkeypatch):
    front, named = study
    with kept_figures(monkeypatch) as figures:
        report.plot_pareto(front, named["nominal"], {"compromise": named["compromise"]}, tmp_path / "pareto.png")
        (figure,) = figures
        assert hidden_legend_entries(figure) == []
        title = figure.axes[0].title
        box, canvas = title.get_window_extent(), figure.bbox
        assert title.get_text() and canvas.x0 <= box.x0 and box.x1 <= canvas.x1 and box.y1 <= canvas.y1  # not clipped


def test_page_is_self_contained_and_bad_arguments_are_named(study, page):
    html = page.read_text()
    assert "<script src=" not in html  # plotly.js embedded: the page works offline
    assert "Plotly.newPlot" in html and "const EXPLORER = " in html
    front, named = study
    with pytest.raises(ValueError, match="colour column 'no_such_column'"):
        explorer.write_explorer(front, named, page.parent / "x.html", colour="no_such_column")
    with pytest.raises(ValueError, match="must include 'nominal'"):
        explorer.write_explorer(front, {"compromise": front[1]}, page.parent / "x.html")


@pytest.fixture(scope="module")
def browser():
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install -e .[dev])")
    chromium, chromedriver = (shutil.which(program) for program in BROWSER_PROGRAMS)
    if not (chromium and chromedriver):
        missing = [p for p, found in zip(BROWSER_PROGRAMS, (chromium, chromedriver), strict=True) if not found]
        pytest.skip(
            f"no headless browser: {', '.join(missing)} not on PATH (Debian: apt-get install chromium chromium-driver)"
        )
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for argument in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--enable-unsafe-swiftshader",
        "--window-size=1400,1100",
    ):
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    service = webdriver.ChromeService(chromedriver)
    driver = webdriver.Chrome(service=service, options=options)
    yield driver
    driver.quit()


def _wait_for(driver, script: str, timeout: float = 30.0):
    """The value of ``script`` once truthy; fails after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    pytest.fail(f"the page never satisfied: {script}")


def _panel(driver) -> dict[str, str]:
    """The panel: design name, the table cells by column, the download link's file and text."""
    cells = driver.execute_script(
        "return Object.fromEntries([...document.querySelectorAll('#panel tr')]"
        ".map(r => [r.dataset.column, r.querySelector('td').textContent]))"
    )
    link = driver.execute_script("const a = document.getElementById('download'); return [a.download, a.href];")
    name = driver.execute_script("return document.getElementById('design-name').textContent")
    return {"name": name, **cells, "file": link[0], "toml": urllib.parse.unquote(link[1].split(",", 1)[1])}


def _assert_panel_shows(panel: dict[str, str], design: dict) -> None:
    assert panel["name"] == design["name"]
    for column in ("ra", "rb", "l1", "l2"):
        assert float(panel[column]) == pytest.approx(1e3 * design["row"][column], abs=0.051)  # mm, 1 decimal
    for column in ("workspace_m3", "peak_torque_nm", "cylinder_diameter_m"):
        assert float(panel[column]) == pytest.approx(design["row"][column], rel=1e-3)  # 4 significant digits
    assert panel["file"] == design["file"] and panel["toml"] == design["toml"]


def test_clicking_a_design_on_the_front_shows_it_in_the_panel(study, page, browser):
    front, named = study
    designs = explorer.explorer_designs(front, named, profiles.worst_cycle(named["nominal"]))
    browser.get(page.as_uri())
    _wait_for(browser, "return window.explorerReady === true")
    _assert_panel_shows(_panel(browser), designs[0])  # the nominal robot at first

    # a real mouse click on front design 2's marker, where plotly draws it
    target = 3
    x, y = browser.execute_script(
        """const gd = document.getElementById('front'), layout = gd._fullLayout;
        const box = gd.getBoundingClientRect(), row = EXPLORER.designs[arguments[0]].row;
        return [box.left + layout._size.l + layout.xaxis.l2p(row.workspace_m3),
                box.top + layout._size.t + layout.yaxis.l2p(row.peak_torque_nm)];""",
        target,
    )
    from selenium.webdriver.common.actions.action_builder import ActionBuilder  # the browser fixture found selenium

    actions = ActionBuilder(browser)
    actions.pointer_action.move_to_location(round(x), round(y)).pause(0.5).click()  # hover first, as a hand does
    actions.perform()
    _wait_for(browser, f"return document.body.dataset.selected === '{target}'", timeout=10.0)
    _assert_panel_shows(_panel(browser), designs[target])
    ring = browser.execute_script("const t = document.getElementById('front').data[2]; return [t.x[0], t.y[0]];")
    assert ring == pytest.approx([designs[target]["row"]["workspace_m3"], designs[target]["row"]["peak_torque_nm"]])
    shown = browser.execute_script("return document.getElementById('torque-plot').data.at(-1).y.slice(0, 5)")
    assert shown == pytest.approx(designs[target]["profile"]["torque"][2][:5])

    # the list selects as a click does
    browser.execute_script(
        "const s = document.getElementById('design-select'); s.value = '1'; s.dispatchEvent(new Event('change'));"
    )
    _assert_panel_shows(_panel(browser), designs[1])
    colours = browser.execute_script("return Array.from(document.getElementById('parallel').data[0].line.color)")
    assert colours == [0, 1, 0, 0]  # the selected design's line is the highlighted one

    # brushing ra to [0.19, 0.23] m in the parallel coordinates dims the designs outside on the front
    browser.execute_script("Plotly.restyle('parallel', {'dimensions[0].constraintrange': [[0.19, 0.23]]}, [0]);")
    opacity = _wait_for(
        browser,
        """const front = document.getElementById('front').data, opacity = (t) => Array.from(t.marker.opacity);
        return front[0].marker.opacity && [opacity(front[0]), opacity(front[1])];""",
        timeout=10.0,
    )
    assert opacity == [[0.15, 1], [1, 1]]  # front designs 0 (ra 0.16 m, dimmed) and 2; nominal and compromise
    severe = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
    assert not severe, severe


def _overlapping_texts(driver, selector: str) -> list[tuple[str, str]]:
    """Pairs of the texts matched by ``selector`` whose bounding boxes (as drawn, px) overlap."""
    boxes = driver.execute_script(
        """return [...document.querySelectorAll(arguments[0])].filter((e) => e.textContent).map((e) => {
            const b = e.getBoundingClientRect(); return [e.textContent, b.left, b.right, b.top, b.bottom]; });""",
        selector,
    )
    return [
        (a[0], b[0])
        for i, a in enumerate(boxes)
        for b in boxes[i + 1 :]
        if a[1] < b[2] and b[1] < a[2] and a[3] < b[4] and b[3] < a[4]
    ]


def test_the_parallel_coordinates_read_at_1400_px(study, page, browser):
    designs = explorer.explorer_designs(*study, profiles.worst_cycle(study[1]["nominal"]))
    browser.get(page.as_uri())
    _wait_for(browser, "return window.explorerReady === true")
    assert browser.execute_script("return window.innerWidth") == 1400
    texts = "#parallel .axis-title, #parallel .axis-extent-text, #parallel .tick text"
    labels = browser.execute_script(
        "return [...document.querySelectorAll('#parallel .axis-title')].map((e) => e.textContent)"
    )
    assert sorted(labels) == sorted(explorer.column_label(c) for c in explorer.PARALLEL_COLUMNS)
    assert browser.execute_script(f"return document.querySelectorAll('{texts}').length") > 3 * len(labels)
    assert _overlapping_texts(browser, texts) == []  # no axis title, range or tick over another

    # the front's legend lists no colour-scaled trace: a swatch has one colour, the colour bar is that trace's key
    legend = browser.execute_script(
        """return document.getElementById('front')._fullData.filter((t) => t.showlegend)
        .map((t) => [t.name, Array.isArray(t.marker.color)]);"""
    )
    assert [name for name, _ in legend] == ["nominal and chosen designs", "selected"]
    assert not any(scaled for _, scaled in legend)

    # a checkbox adds an axis, and the axes kept keep their brushes
    browser.execute_script("Plotly.restyle('parallel', {'dimensions[0].constraintrange': [[0.19, 0.23]]}, [0]);")
    browser.execute_script(
        """const box = document.querySelector('#axes input[value="drive_max_speed_rad_s"]');
        box.checked = true; box.dispatchEvent(new Event('change', {bubbles: true}));"""
    )
    dimensions = browser.execute_script(
        "return document.getElementById('parallel').data[0].dimensions.map((d) => [d.label, d.constraintrange]);"
    )
    assert [label for label, _ in dimensions] == [
        explorer.column_label(c)
        for c in explorer.parallel_columns(designs)
        if c in {*explorer.PARALLEL_COLUMNS, "drive_max_speed_rad_s"}
    ]
    assert dimensions[0] == ["ra (m)", [0.19, 0.23]] and all(brush is None for _, brush in dimensions[1:])
    severe = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
    assert not severe, severe
