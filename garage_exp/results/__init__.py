"""A job's numbers and pictures: the frame table and its summaries (table), statistics (stats), dataset labels
(labels), and plots and annotated frames (figures)."""
