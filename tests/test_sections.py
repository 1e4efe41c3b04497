"""``iap_mjx.sections``: a script rewrites its own named section of a markdown file and
reads it back; the rest of the file stays as it was."""

from __future__ import annotations

from iap_mjx import sections


def test_a_section_reads_back_what_was_written_and_leaves_the_others(tmp_path):
    path = tmp_path / "RESULTS.md"
    sections.write_results_section(path, "a", "first\n\nbody\n")
    sections.write_results_section(path, "b", "other")
    assert sections.read_section(path, "a") == "first\n\nbody"
    sections.write_results_section(path, "a", "second")
    assert (sections.read_section(path, "a"), sections.read_section(path, "b")) == ("second", "other")
    assert sections.read_section(path, "c") is None
    assert (
        path.read_text()
        == "# Results\n\n<!-- BEGIN a -->\nsecond\n<!-- END a -->\n\n<!-- BEGIN b -->\nother\n<!-- END b -->\n"
    )
