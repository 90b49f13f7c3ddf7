# %% [markdown]
# # first_design
#
# (being written)
