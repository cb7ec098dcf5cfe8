"""Who may do what on a site: certificates, access rules and the Zenoh configs that carry them."""
