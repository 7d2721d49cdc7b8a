"""``report.html``: tables 5-9 and every plot in one file, nothing fetched from the network."""

import base64
from html.parser import HTMLParser
import re

from rths_review import report_html

SUMMARY = {
    'record': 'kobe', 'scale': 0.135, 'specimen': 'valve4', 'mode': 'lockstep', 'fs_hz': 1024.0,
    'steps': 4096, 'duration_s': 4.0, 'compensator': {'scheme': 'wls', 'n_taps': 400},
    'delay_ms_before': 13.932, 'delay_ms_after': 0.297,
    'tracking_rel_rms_pct_before': 5.71, 'tracking_rel_rms_pct_after': 0.09,
    'max_disp_2nd_m': 3.8123e-3, 'rms_disp_2nd_m': 5.4981e-4,
    'uncontrolled_max_disp_2nd_m': 5.4563e-3, 'uncontrolled_rms_disp_2nd_m': 8.5153e-4,
    'reduction_max_pct': 30.1, 'reduction_rms_pct': 35.4,
    'rths_vs_reference_rel_rms_pct': 0.09, 'deadline_misses': 0, 'deadline_miss_pct': 0.0,
    'safety_faults': ['step 7: <script>'],
}


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.urls, self.cells = [], []

    def handle_starttag(self, tag, attrs):
        self.urls += [v for k, v in attrs if k in ('src', 'href') and v]

    def handle_data(self, data):
        self.cells.append(data.strip())


def _png(tmp_path, name):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 1))
    ax.plot([0, 1], [0, 1])
    fig.savefig(tmp_path / name, dpi=50)
    plt.close(fig)
    return (tmp_path / name).read_bytes()


def test_report_embeds_every_plot_and_fetches_nothing(tmp_path):
    pngs = {name: _png(tmp_path, name) for name in report_html.PLOTS}
    path = report_html.write_report(tmp_path, SUMMARY)
    text = path.read_text(encoding='utf-8')
    parser = _Links()
    parser.feed(text)
    assert not [u for u in parser.urls if re.match(r'\s*(https?:)?//', u)], parser.urls
    embedded = [base64.b64decode(u.split(',', 1)[1]) for u in parser.urls
                if u.startswith('data:image/png;base64,')]
    assert sorted(embedded) == sorted(pngs.values())      # every plot, byte for byte
    assert len(parser.urls) == len(pngs)                  # and nothing else linked
    # the tables' figures are on the page, the fault text is escaped
    for cell in ('13.932', '0.297', '5.71', '0.09', '5.4563e-03', '30.1', '35.4'):
        assert cell in parser.cells, cell
    assert '<script>' not in text and '&lt;script&gt;' in text


def test_report_without_plots_still_has_the_tables(tmp_path):
    text = report_html.write_report(tmp_path, SUMMARY).read_text()
    assert 'Table 5' in text and 'Table 9' in text and '<img' not in text
