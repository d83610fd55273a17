"""The link behind and ahead: the link model, the rate tables and the retreat to where the link held."""
