"""The agent process: one OS process per agent, running the split-spectrum protocol over Zenoh."""
