"""Import demonstrations into a :class:`pbicrl.data.Dataset`.

* :func:`read_csv`, :func:`read_parquet`, :func:`read_table` - one row per state with trajectory id, group and
  feature columns (Parquet needs ``pip install "pbicrl[io]"``);
* :func:`from_minari` - a local Minari dataset plus a user feature function (needs ``pip install "minari[hdf5]"``).

Optional dependencies are imported only when a reader is called.
"""

from __future__ import annotations

from pbicrl.io.csv import TableError, columns_to_dataset, read_csv, read_parquet, read_table, write_csv
from pbicrl.io.minari import from_minari, load_feature_function

__all__ = ["TableError", "columns_to_dataset", "read_csv", "read_parquet", "read_table", "write_csv", "from_minari",
           "load_feature_function"]
