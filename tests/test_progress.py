"""The progress bar: plain log lines where the output is not a terminal, silence when disabled."""

from emgail_jax.host.progress import ProgressBar


def test_logs_plain_lines_with_the_latest_fields_when_not_a_terminal(capsys):
    with ProgressBar("training", 20, {"ERD": "-", "acc": "-"}, completed=10) as bar:
        bar.log_every_s = 1e9  # only the first update and the last iteration print
        bar.update(5, ERD="0.500", acc="0.700")
        bar.update(5, ERD="0.250")
    out = capsys.readouterr().out
    assert "training 15/20  ERD 0.500  acc 0.700  " in out
    assert "training 20/20  ERD 0.250  acc 0.700  " in out


def test_disabled_bar_prints_nothing(capsys):
    with ProgressBar("training", 10, {"ERD": "-"}, enabled=False) as bar:
        bar.update(10, ERD="0.1")
    assert capsys.readouterr().out == ""
