"""Reports: interactive offline HTML pages and PNG pictures of results."""
