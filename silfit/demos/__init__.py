"""The demos (``silfit demo``): a shipped subject fitted end to end, body and whole body."""
