"""Reports: ``lessmap eval``'s evaluation and Markdown, the measured figures of RESULTS.md."""
