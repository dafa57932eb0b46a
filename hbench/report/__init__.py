"""The comparison report: HTML, LaTeX and PDF, its figures and their style, and the section on
methods beyond the paper."""
