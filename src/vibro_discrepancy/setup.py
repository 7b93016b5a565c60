from setuptools import find_packages, setup

package_name = "vibro_discrepancy"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="vibro maintainers",
    maintainer_email="vibro@example.com",
    description=("Discrepancy analysis: locate where the models and a recording disagree, name the physics the model "
                 "left out, model it and show the fit improve; discrepancy node."),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "discrepancy = vibro_ros.entry:discrepancy",
        ],
    },
)
