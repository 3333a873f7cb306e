"""Files: tracks (CSV, TUM), files that appear whole or not at all, the bounded YAML reader, and
the output policy every command follows."""
