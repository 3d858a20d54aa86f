"""What every stage stands on: errors and exit codes, paths, the config schema, the plugin allow-list, and the
process's state."""
